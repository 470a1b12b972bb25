"""Domain errors of angiohull.

Every error a user can trigger with bad input is one of these. They derive from :class:`ValueError`
so that code written against plain NumPy/scikit-image conventions keeps working, and each message
says what was received, what was expected and, where possible, how to fix it.
"""

from __future__ import annotations

__all__ = [
    "AngiohullError",
    "GeometryError",
    "StudyError",
    "TreeError",
    "OutputError",
    "ReconstructionError",
    "EmptyHullError",
    "DicomError",
    "SegmentationError",
    "DicomGeometryWarning",
    "TreeWarning",
    "AgreementWarning",
    "InputWarning",
    "QcaError",
    "ViewerError",
]


class AngiohullError(ValueError):
    """Base class of all errors raised for bad input to angiohull."""


class GeometryError(AngiohullError):
    """An acquisition geometry (C-arm parameters or projection matrix) is invalid."""


class StudyError(AngiohullError):
    """A study folder, its ``study.yaml`` or one of the files it names is invalid.

    The message starts with the file (and, for YAML, the field) that is at fault.
    """


class DicomError(StudyError):
    """A DICOM file cannot be used: not an X-ray angiogram, a missing or absurd tag, undecodable pixels.

    The message starts with the file and names the tag (keyword and ``(gggg,eeee)``) at fault and,
    where it helps, what to install or change.
    """


class SegmentationError(AngiohullError):
    """The input or the parameters of the vessel segmentation are invalid."""


class TreeError(AngiohullError):
    """A vessel tree is invalid (shapes, non-finite values, radii <= 0, not a tree), or a tree
    operation got arguments it cannot use (an unwritable export path, a missing true tree)."""


class QcaError(AngiohullError):
    """A quantitative coronary analysis cannot do what was asked (an empty tree, a branch too short
    for the reference fit, a segment or branch that does not exist); the message names it."""


class OutputError(AngiohullError):
    """An output folder or file cannot be written (the message names the path and the reason);
    nothing of the outputs being written is left behind."""


class ViewerError(AngiohullError):
    """The interactive viewer cannot be built: a result folder without what it needs, a bad layer,
    or the plotly package missing."""


class ReconstructionError(AngiohullError):
    """The inputs of a reconstruction are inconsistent (shapes, options)."""


class EmptyHullError(ReconstructionError):
    """Carving removed every point of the cube of interest.

    Attributes
    ----------
    view_index : int
        Index of the view whose filtering removed the last points.
    view_name : str
        Its name, where one was given.
    points_before : int
        How many points were still alive before that view was applied.
    """

    def __init__(self, message: str, *, view_index: int, view_name: str, points_before: int):
        super().__init__(message)
        self.view_index = view_index
        self.view_name = view_name
        self.points_before = points_before


class DicomGeometryWarning(UserWarning):
    """A geometry value was not in the DICOM file where it belongs and was derived from another tag.

    The message names the file, the missing tag, the value assumed and the tag(s) it came from,
    e.g. ``IM1.dcm: ImagerPixelSpacing (0018,1164) is missing; assumed 0.390625 x 0.390625 mm from
    FieldOfViewDimensions (0018,1149) = [200, 200] mm over 512 x 512 pixels``.
    """


class TreeWarning(UserWarning):
    """A reconstruction's vessel tree could not be built, or was built from less than the hull
    (parts dropped); the message says what and why."""


class AgreementWarning(UserWarning):
    """The views disagree: the visual hull of all views covers too little of some view's mask (a
    geometry off by pixels, or masks that do not show the same vessels), with or without
    calibration. The message names the views and their coverage and says what to try."""


class InputWarning(UserWarning):
    """An input that angiohull can use but that is probably not what was meant: a mask that is
    mostly vessel or a few pixels small, a DICOM header that contradicts itself, pixel data that
    needed repair. The message names the file and the field or tag, and what looks wrong.

    The command line prints it as one ``angiohull: warning: ...`` line.
    """
