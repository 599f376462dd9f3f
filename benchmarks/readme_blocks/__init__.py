"""The README's generated blocks, one module per README section; :mod:`readme_tables` puts them in the README."""
