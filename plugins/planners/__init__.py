"""Built-in planner plugins: safe_prm, optmis, segmented_astar, retraction, and the OMPL bridge."""
