"""Runners for external reference SPH codes (PySPH, SPlisHSPlasH) used by ``sph bench``."""
