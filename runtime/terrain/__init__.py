"""Terrain maps for terrain-aided navigation: BathymetryMap, its compiled lookup, and map builders."""
from .kernel import BilinearLookup
from .maps import MAPS, BathymetryMap, synthetic_arctic, topobathy_window

__all__ = ["MAPS", "BathymetryMap", "BilinearLookup", "synthetic_arctic", "topobathy_window"]
