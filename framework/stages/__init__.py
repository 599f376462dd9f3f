"""The built-in stage kinds, one module each: ``plan``, ``simulate``, ``execute`` and ``guide``.

Each module exports its kind (a :class:`surgiplan.kinds.StageKind`): its YAML keys, the hook and interface
of the plugins it runs, its statuses, how it runs, and what the summary and the report show of it. They
register through the entry point ``stages`` (``surgiplan.stages.builtin``), exactly as a third party's kinds do.
"""
