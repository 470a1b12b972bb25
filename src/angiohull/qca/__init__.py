"""Quantitative coronary analysis (3D QCA) of a vessel tree: lengths, diameters, stenoses,
bifurcation angles, foreshortening, overlap and working views.

* :mod:`.vessels`: the vessels a tree's branches make up (a branch that runs into a stub and goes
  on as its child is one vessel with it);
* :mod:`.profile`: a branch's diameter profile, its healthy taper (the reference), lesions, minimal
  lumen diameter, percent diameter stenosis, lesion length;
* :mod:`.bifurcations`: proximal and distal angles, Medina flags;
* :mod:`.views`: foreshortening and overlap in a view, the view map of a segment and its best
  C-arm angles;
* :mod:`.attenuation`: lumen diameters read from the angiograms' attenuation (a blurred round
  lumen fitted across the vessel in each view): a lesion's minimal lumen diameter where a mask's
  threshold cannot give it (``analyse_tree(..., attenuation=)``);
* :mod:`.analysis`: :func:`analyse_tree`, everything at once, with its tables.

Works on any :class:`~angiohull.tree.VesselTree` (a reconstruction's or a true one); arrays in,
arrays out, no files (the CLI writes ``qca.json``, ``lesions.csv`` and ``branches.csv``).
"""

from __future__ import annotations

from .analysis import (BRANCH_COLUMNS, LESION_COLUMNS, BranchQca, QcaResult, QcaSettings, analyse_tree,
                       branch_profile, segment_view_map, vessel_profiles)
from .attenuation import (AttenuationFitSettings, AttenuationMeasurement, ViewCalibration, calibrate_views,
                          image_diameters)
from .bifurcations import BifurcationAnalysis, BifurcationSettings, analyse_bifurcations
from .profile import DiameterProfile, Lesion, ProfileSettings, ReferenceFit, reference_fit, window_lesion_length_mm
from .vessels import TreeVessels, Vessel, VesselSettings, tree_vessels
from .views import ViewMap, ViewMapSettings, foreshortening, view_map

__all__ = [
    "analyse_tree", "branch_profile", "vessel_profiles", "segment_view_map", "QcaSettings", "QcaResult", "BranchQca",
    "LESION_COLUMNS", "BRANCH_COLUMNS",
    "ProfileSettings", "DiameterProfile", "ReferenceFit", "Lesion", "reference_fit", "window_lesion_length_mm",
    "VesselSettings", "Vessel", "TreeVessels", "tree_vessels",
    "BifurcationSettings", "BifurcationAnalysis", "analyse_bifurcations",
    "ViewMapSettings", "ViewMap", "view_map", "foreshortening",
    "AttenuationFitSettings", "ViewCalibration", "AttenuationMeasurement", "calibrate_views", "image_diameters",
]
