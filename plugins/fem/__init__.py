"""Built-in deformable-model plugins: stvk (nonlinear St. Venant-Kirchhoff FEM)."""
