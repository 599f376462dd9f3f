"""surgiplan's planner plugins, one package per method (each registers itself through an entry point):

* :mod:`.safe_prm` — paper 000: proficiency-based safe PRM with path repair;
* :mod:`.optmis` — paper 001, offline: optMIS search space, optimal paths, repository;
* :mod:`.segmented_astar` — paper 001, online: segmented pathmap, A*, Table 1;
* :mod:`.retraction` — paper 002: tissue-retraction plans and grasp selection on FEM states;
* :mod:`.ompl_bridge` — OMPL's planners behind the same interface (the reference peers).

The packages do not import one another (the import contracts in
``pyproject.toml``), except :mod:`.segmented_astar`, which compresses the
repository :mod:`.optmis` computes (one method of paper 001, in two stages).
Shared path tools are in the core, :mod:`surgiplan.paths`.
"""
