"""AVS services: each a package with a pure core, a thin node and a ``__main__``."""
