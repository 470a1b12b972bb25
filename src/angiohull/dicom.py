"""X-ray angiography (XA) DICOM files: C-arm geometry per frame, pixel data, frame selection.

The geometry of a view is read from the header into a :class:`~angiohull.geometry.CArmGeometry`
(docs/conventions.md, "Geometry conventions"), whose :meth:`~angiohull.geometry.CArmGeometry.projection` is
the view's 3x4 matrix:

===========================  ===========================================================================
geometry                      tags (classic XA; Enhanced XA: per-frame functional group, then shared group)
===========================  ===========================================================================
primary angle (LAO +)         PositionerPrimaryAngle (0018,1510); Enhanced: PositionerPositionSequence (0018,9405)
secondary angle (CRA +)       PositionerSecondaryAngle (0018,1511); idem
SID                           DistanceSourceToDetector (0018,1110); Enhanced: XRayGeometrySequence (0018,9476)
SOD                           DistanceSourceToPatient (0018,1111); Enhanced: DistanceSourceToIsocenter (0018,9402)
pixel spacing (detector)      ImagerPixelSpacing (0018,1164); Enhanced: FramePixelDataPropertiesSequence (0028,9443)
image shape                   Rows (0028,0010), Columns (0028,0011)
===========================  ===========================================================================

Fallbacks, each announced with a :class:`~angiohull.errors.DicomGeometryWarning` that names the
missing tag, the value assumed and where it came from: without ImagerPixelSpacing, the spacing is
FieldOfViewDimensions (0018,1149) (Enhanced: FieldOfViewDimensionsInFloat (0018,9461)) divided by
the matrix size, else IntensifierSize (0018,1162) divided by the larger of Rows and Columns. Every
other missing geometry tag is an error.

Rotational runs (classic XA, PS3.3 C.8.7.5.1.3): PositionerPrimaryAngleIncrement (0018,1520) and
PositionerSecondaryAngleIncrement (0018,1521) hold either one value, the average change per frame
(frame ``i`` is at ``angle + i * increment``), or one value per frame, the offsets from the
Positioner Primary/Secondary Angle of the run (frame ``i`` is at ``angle + increment[i]``; the
standard allows absolute angles there with the angle attributes set to 0, which this reads the
same way). Enhanced XA files carry absolute per-frame angles in their functional groups.

Frames are numbered from 0 everywhere in angiohull (DICOM frame number ``n`` is index ``n - 1``).

Automatic frame selection (:func:`select_frame`): the frame whose vessels stand out most
(:func:`~angiohull.segmentation.vessel_contrast_score`), or, when the file says which frames are
end-diastolic, the end-diastolic frame nearest to it. End-diastolic frames are read from (first
that is present): Enhanced XA CardiacCyclePosition (0018,9236) = END_DIASTOLE in the per-frame
FrameContentSequence; RWavePointer (0028,6040) (frame numbers of the R waves); RWaveTimeVector
(0018,6060) (ms from the start of the run) matched to the frame times from FrameTimeVector
(0018,1065) or FrameTime (0018,1063). ECG waveforms (5400,0100) are not analysed.

Pixel data are decoded by pydicom; compressed transfer syntaxes need a decoder plugin (angiohull
depends on pylibjpeg with pylibjpeg-libjpeg, which covers the JPEG family including JPEG
Lossless SV1 of most cardiac archives).
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np
import pydicom
from pydicom.dataset import Dataset
from pydicom.errors import InvalidDicomError
from pydicom.multival import MultiValue

from .errors import DicomError, DicomGeometryWarning, GeometryError, InputWarning
from .geometry import CArmGeometry, format_clinical_angles

__all__ = [
    "XAFrameGeometry",
    "XAHeader",
    "FrameSelection",
    "XAView",
    "read_xa_header",
    "read_xa_frames",
    "read_xa_frame",
    "select_frame",
    "read_xa_view",
    "XA_SOP_CLASS",
    "ENHANCED_XA_SOP_CLASS",
]

PathLike = Union[str, Path]

#: SOP Class UID of X-Ray Angiographic Image Storage.
XA_SOP_CLASS = "1.2.840.10008.5.1.4.1.1.12.1"
#: SOP Class UID of Enhanced XA Image Storage.
ENHANCED_XA_SOP_CLASS = "1.2.840.10008.5.1.4.1.1.12.1.1"
_XA_CLASSES = {XA_SOP_CLASS: "XA", ENHANCED_XA_SOP_CLASS: "Enhanced XA"}

# Plausible ranges; values outside are reported as errors (they are encoding mistakes, not C-arms).
SID_RANGE_MM = (200.0, 3000.0)
SOD_MIN_MM = 50.0
SPACING_RANGE_MM = (0.01, 5.0)

_TAGS = {
    "PositionerPrimaryAngle": "(0018,1510)",
    "PositionerSecondaryAngle": "(0018,1511)",
    "PositionerPrimaryAngleIncrement": "(0018,1520)",
    "PositionerSecondaryAngleIncrement": "(0018,1521)",
    "DistanceSourceToDetector": "(0018,1110)",
    "DistanceSourceToPatient": "(0018,1111)",
    "DistanceSourceToIsocenter": "(0018,9402)",
    "ImagerPixelSpacing": "(0018,1164)",
    "FieldOfViewDimensions": "(0018,1149)",
    "FieldOfViewDimensionsInFloat": "(0018,9461)",
    "FieldOfViewShape": "(0018,1147)",
    "IntensifierSize": "(0018,1162)",
    "Rows": "(0028,0010)",
    "Columns": "(0028,0011)",
    "NumberOfFrames": "(0028,0008)",
    "Modality": "(0008,0060)",
    "SOPClassUID": "(0008,0016)",
    "RWavePointer": "(0028,6040)",
    "RWaveTimeVector": "(0018,6060)",
    "FrameTime": "(0018,1063)",
    "FrameTimeVector": "(0018,1065)",
    "CardiacCyclePosition": "(0018,9236)",
    "PositionerPositionSequence": "(0018,9405)",
    "XRayGeometrySequence": "(0018,9476)",
    "FramePixelDataPropertiesSequence": "(0028,9443)",
    "FieldOfViewSequence": "(0018,9432)",
    "FrameContentSequence": "(0020,9111)",
    "SamplesPerPixel": "(0028,0002)",
    "PatientPosition": "(0018,5100)",
    "FieldOfViewRotation": "(0018,7032)",
    "FieldOfViewHorizontalFlip": "(0018,7034)",
    "TransferSyntaxUID": "(0002,0010)",
    "MediaStorageSOPClassUID": "(0002,0002)",
    "PixelData": "(7FE0,0010)",
}

_MODALITIES = ("XA", "RF")
"""Modalities of X-ray angiograms (RF: fluoroscopy acquired on the same C-arms)."""


def _tag(keyword: str) -> str:
    return f"{keyword} {_TAGS.get(keyword, '')}".rstrip()


# -- records -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class XAFrameGeometry:
    """The acquisition geometry of one frame, as read from the header.

    Attributes
    ----------
    frame : int
        Frame index, from 0.
    primary_deg, secondary_deg : float
        C-arm angles (LAO +, CRA +), degrees.
    sid_mm, sod_mm : float
        Source-to-detector and source-to-isocentre distances, mm.
    pixel_spacing_mm : (float, float)
        (row, column) spacing at the detector, mm.
    image_shape : (int, int)
        (rows, cols).
    """

    frame: int
    primary_deg: float
    secondary_deg: float
    sid_mm: float
    sod_mm: float
    pixel_spacing_mm: tuple[float, float]
    image_shape: tuple[int, int]

    def carm(self) -> CArmGeometry:
        """This frame's :class:`~angiohull.geometry.CArmGeometry` (principal point at the image centre)."""
        return CArmGeometry(self.primary_deg, self.secondary_deg, self.sid_mm, self.sod_mm,
                            self.pixel_spacing_mm, self.image_shape)

    @property
    def clinical(self) -> str:
        """The angles as an angiographer says them, e.g. ``"LAO 31.3 CRA 0.1"``."""
        return format_clinical_angles(self.primary_deg, self.secondary_deg)

    def _pose(self) -> tuple[float, ...]:
        return (self.primary_deg, self.secondary_deg, self.sid_mm, self.sod_mm, *self.pixel_spacing_mm)


@dataclass(frozen=True)
class XAHeader:
    """What angiohull reads from the header of an XA file (no pixel data).

    Attributes
    ----------
    path : Path
        The file.
    modality : str
        Modality (0008,0060), e.g. ``"XA"``.
    sop_class : str
        ``"XA"`` or ``"Enhanced XA"``.
    n_frames : int
        Number of frames (1 for a single-frame file).
    image_shape : (int, int)
        (rows, cols).
    frames : tuple of XAFrameGeometry
        The geometry of every frame.
    angle_source : str
        Where the angles came from (tags, increments or functional groups).
    spacing_source : str
        Where the pixel spacing came from (the tag, or the fallback and its values).
    end_diastolic_frames : tuple of int
        Frames (from 0) marked or derived as end-diastolic; empty when the file has no ECG data.
    ecg_source : str or None
        The tag the end-diastolic frames came from.
    frame_times_ms : tuple of float or None
        Time of each frame from the start of the run, ms, when the file gives it.
    transfer_syntax : str
        The transfer syntax's name.
    photometric : str
        Photometric Interpretation (0028,0004).
    sop_instance_uid : str
        SOP Instance UID (0008,0018): the image's identity ("" when the file has none).
    """

    path: Path
    modality: str
    sop_class: str
    n_frames: int
    image_shape: tuple[int, int]
    frames: tuple[XAFrameGeometry, ...]
    angle_source: str
    spacing_source: str
    end_diastolic_frames: tuple[int, ...]
    ecg_source: Optional[str]
    frame_times_ms: Optional[tuple[float, ...]]
    transfer_syntax: str
    photometric: str
    sop_instance_uid: str = ""

    @property
    def varying_geometry(self) -> bool:
        """True when the frames do not all share one geometry (a rotational run)."""
        first = self.frames[0]._pose()
        return any(frame._pose() != first for frame in self.frames[1:])

    def check_frame(self, frame: Any) -> int:
        """``frame`` as an index into this run, or a :class:`DicomError` naming the valid range."""
        if isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, np.integer)):
            raise DicomError(f"{self.path}: frame must be an integer index from 0, got {frame!r}")
        if not 0 <= int(frame) < self.n_frames:
            raise DicomError(
                f"{self.path}: frame {int(frame)} does not exist; the run has {self.n_frames} frame(s), "
                f"indices 0 to {self.n_frames - 1} (angiohull counts frames from 0)"
            )
        return int(frame)

    def geometry(self, frame: Optional[int] = None) -> CArmGeometry:
        """The C-arm geometry of one frame.

        Parameters
        ----------
        frame : int, optional
            Frame index from 0. May be omitted when every frame has the same geometry.

        Raises
        ------
        DicomError
            If the frame does not exist, or is omitted in a run whose geometry varies by frame.
        """
        if frame is None:
            if self.varying_geometry:
                raise DicomError(
                    f"{self.path}: the geometry changes from frame to frame ({self.angle_source}); "
                    f"give a frame index (0 to {self.n_frames - 1})"
                )
            frame = 0
        return self.frames[self.check_frame(frame)].carm()


@dataclass(frozen=True)
class FrameSelection:
    """Which frame of a run was chosen, and why.

    Attributes
    ----------
    frame : int
        The chosen frame, from 0.
    reason : str
        A sentence for reports, e.g. ``"most contrast (frame 9 of 14)"``.
    scores : tuple of float or None
        The contrast score of every frame, when they were computed.
    most_contrast_frame : int or None
        The frame with the highest score.
    end_diastolic_frames : tuple of int
        The end-diastolic frames considered.
    """

    frame: int
    reason: str
    scores: Optional[tuple[float, ...]] = None
    most_contrast_frame: Optional[int] = None
    end_diastolic_frames: tuple[int, ...] = ()


@dataclass(frozen=True, eq=False)
class XAView:
    """One frame of an XA file ready for the pipeline: its image, geometry and header.

    Attributes
    ----------
    header : XAHeader
    frame : int
        The frame, from 0.
    image : ndarray, shape (rows, cols)
        Its pixels as stored (MONOCHROME1 inverted so that brighter = more X-ray intensity).
    carm : CArmGeometry
        Its geometry.
    selection : FrameSelection
        How the frame was chosen.
    """

    header: XAHeader
    frame: int
    image: np.ndarray
    carm: CArmGeometry
    selection: FrameSelection


# -- reading the header ------------------------------------------------------------------------
def _tag_name(tag: Any) -> str:
    """``Keyword (gggg,eeee)`` of a tag (private or unknown tags: just the number)."""
    from pydicom.datadict import keyword_for_tag
    from pydicom.tag import Tag

    tag = Tag(tag)
    number = f"({tag.group:04X},{tag.element:04X})"
    keyword = keyword_for_tag(tag)
    return f"{keyword} {number}" if keyword else number


def _parse_all(path: Path, ds: Dataset, where: str = "", depth: int = 0) -> None:
    """Decode every element now (pydicom decodes lazily, on first access), so that a damaged one
    (an unknown value representation, a value that does not fit its VR) is a DicomError naming
    the file and the tag, not an exception in the middle of the geometry."""
    for tag in list(ds.keys()):
        try:
            element = ds[tag]
            value = element.value
        except Exception as exc:  # pydicom raises NotImplementedError, ValueError, KeyError, ... here
            detail = " ".join(str(exc).split())
            raise DicomError(f"{path}: {_tag_name(tag)}{where} is damaged and cannot be read ({type(exc).__name__}: "
                             f"{detail}); the file's header is corrupt") from None
        if element.VR == "SQ" and value is not None and depth < 8:
            for index, item in enumerate(value):
                _parse_all(path, item, f"{where} in {_tag_name(tag)}[{index}]", depth + 1)


_MAX_PYDICOM_WARNINGS = 3


def _condensed(text: str, limit: int = 200) -> str:
    """One short printable line of a message (pydicom quotes raw bytes of damaged values)."""
    line = " ".join("".join(c if c.isprintable() else " " for c in text).split())
    return line if len(line) <= limit else line[:limit - 1] + "…"


def _pydicom_warnings(path: Path, caught: Sequence[warnings.WarningMessage], tag: str) -> None:
    """Re-issue what pydicom warned about while reading ``path`` as one-line InputWarnings naming the tag
    (at most a few, shortened: a damaged header can make pydicom warn at length)."""
    seen: list[str] = []
    for item in caught:
        if issubclass(item.category, (DicomGeometryWarning, InputWarning)):
            warnings.warn(item.message, item.category, stacklevel=3)
            continue
        detail = _condensed(str(item.message))
        if detail not in seen:
            seen.append(detail)
    for detail in seen[:_MAX_PYDICOM_WARNINGS]:
        warnings.warn(f"{path}: {tag}: {detail} (pydicom, while reading the file)", InputWarning, stacklevel=3)
    if len(seen) > _MAX_PYDICOM_WARNINGS:
        warnings.warn(f"{path}: {tag}: and {len(seen) - _MAX_PYDICOM_WARNINGS} more warning(s) of pydicom",
                      InputWarning, stacklevel=3)


_PIXEL_TAGS = (0x7FE00008, 0x7FE00009, 0x7FE00010)
"""FloatPixelData, DoubleFloatPixelData, PixelData: where pydicom's ``stop_before_pixels`` stops."""


def _cut_short(path: Path, size: int, where: str) -> DicomError:
    return DicomError(f"{path}: the file ends early, inside its header ({where}; {size} bytes, before any "
                      f"{_tag('PixelData')}): it is truncated; copy it again from its source")


def _where_header_ends(ds: Dataset, size: int) -> Optional[str]:
    """Where a data set read to the end of its file without reaching the pixel data stops (the last
    element read, from the file's own offsets), or None when it reads as a mislabelled transfer syntax
    rather than a cut-short file (its first element's tag is neither a standard nor a private one)."""
    from pydicom.datadict import dictionary_has_tag

    container = ds if len(ds) else getattr(ds, "file_meta", None)
    if container is None or not len(container):
        return "before its first element"
    tags = list(container.keys())
    if container is ds and not (dictionary_has_tag(tags[0]) or tags[0].is_private):
        return None  # e.g. Explicit VR Little Endian read as Big Endian: (0008,0016) comes out (0800,1600)
    last = container.get_item(tags[-1])
    name = _tag_name(tags[-1])
    length, start = getattr(last, "length", None), getattr(last, "value_tell", None)
    if length is None or start is None or length == 0xFFFFFFFF:
        return f"in or after {name}"
    end = start + length
    if end > size:
        return f"in the value of {name}, {end - size} byte(s) short of its length {length}"
    return f"after {name}" if end == size else f"in the element after {name}"


def _read_dataset(path: Path, *, pixels: bool, caught: Optional[list] = None) -> Dataset:
    """Read a DICOM file (every element decoded); what pydicom warned about is appended to ``caught``.

    A file that ends before its pixel data (an XA image holds them last) is a DicomError that says it
    is truncated: pydicom reads such a file quietly up to its end, and what is cut off would only
    show as missing tags or as values that cannot be decoded.
    """
    if not path.exists():
        raise DicomError(f"{path}: file not found; expected an X-ray angiography DICOM file")
    if not path.is_file():
        raise DicomError(f"{path}: is not a regular file; expected an X-ray angiography DICOM file")
    with warnings.catch_warnings(record=True) as recorded:
        warnings.simplefilter("always")
        try:
            size = path.stat().st_size
            with open(path, "rb") as handle:
                try:
                    ds = pydicom.dcmread(handle, stop_before_pixels=not pixels)
                except InvalidDicomError:
                    raise
                except Exception as exc:  # struct.error, BytesLengthException, ...: at the end, a tag or value cut
                    if handle.tell() < size:
                        raise DicomError(f"{path}: cannot read as DICOM ({type(exc).__name__}: {exc}); the file may "
                                         f"be truncated or damaged") from None
                    raise _cut_short(path, size, f"pydicom: {type(exc).__name__}: {_condensed(str(exc), 80)}") from None
                stopped = handle.tell()
            ended = next((str(w.message) for w in recorded if "end of file" in str(w.message).lower()), None)
            if ended is not None:  # pydicom warns, and returns what it read (or nothing: an empty data set)
                said = re.sub(r"\s*found in file .*$", "", ended)
                raise DicomError(f"{path}: the file ends early (pydicom: {said}): it is truncated; copy it again "
                                 f"from its source")
            reached = stopped < size if not pixels else any(tag in ds for tag in _PIXEL_TAGS)
            where = None if reached else _where_header_ends(ds, size)
            if where is not None and where.startswith("after "):  # its last element whole: no image, or cut there
                raise DicomError(f"{path}: has no {_tag('PixelData')}: the file ends {where} ({size} "
                                 f"bytes), as a DICOM file without an image does, or one cut short right there (then "
                                 f"copy it again from its source)")
            if where is not None:  # pydicom stops quietly where a file cut short ends: the rest is simply missing
                raise _cut_short(path, size, where)
            _parse_all(path, ds)
        except DicomError:
            raise
        except InvalidDicomError as exc:
            raise DicomError(f"{path}: is not a DICOM file ({exc}); expected a DICOM Part 10 file of an X-ray angiogram") from None
        except (OSError, EOFError, ValueError, KeyError, TypeError, NotImplementedError) as exc:
            raise DicomError(f"{path}: cannot read as DICOM ({type(exc).__name__}: {exc}); the file may be truncated or damaged") from None
    if caught is not None:
        caught.extend(recorded)
    return ds


def _present(container: Optional[Dataset], keyword: str) -> bool:
    """True when ``keyword`` is in ``container`` with a non-empty value."""
    if container is None or keyword not in container:
        return False
    value = container[keyword].value
    if value is None:
        return False
    if isinstance(value, str):
        return value.strip() != ""
    try:
        return len(value) > 0
    except TypeError:
        return True


def _numbers(path: Path, container: Dataset, keyword: str, where: str = "") -> list[float]:
    """The values of a numeric tag as floats (a DicomError names the tag when they are not numbers)."""
    value = container[keyword].value
    items = list(value) if isinstance(value, (list, tuple, MultiValue)) else [value]
    numbers = []
    for item in items:
        try:
            number = float(item)
        except (TypeError, ValueError):
            raise DicomError(f"{path}: {_tag(keyword)}{where} is not a number: {value!r}") from None
        if not math.isfinite(number):
            raise DicomError(f"{path}: {_tag(keyword)}{where} is not finite: {value!r}")
        numbers.append(number)
    return numbers


def _single(path: Path, container: Dataset, keyword: str, where: str = "") -> float:
    values = _numbers(path, container, keyword, where)
    if len(values) != 1:
        raise DicomError(f"{path}: {_tag(keyword)}{where} must hold one number, got {len(values)}: {values}")
    return values[0]


def _item(sequence_owner: Optional[Dataset], keyword: str) -> Optional[Dataset]:
    """The first item of a sequence, or None."""
    if sequence_owner is None or keyword not in sequence_owner:
        return None
    sequence = sequence_owner[keyword].value
    return sequence[0] if sequence else None


class _Groups:
    """Lookup of attributes in the functional groups of an Enhanced multi-frame file."""

    def __init__(self, ds: Dataset):
        self.per_frame = list(ds.get("PerFrameFunctionalGroupsSequence", None) or [])
        shared = ds.get("SharedFunctionalGroupsSequence", None) or []
        self.shared = shared[0] if shared else None
        self.enhanced = bool(self.per_frame) or self.shared is not None

    def find(self, frame: int, sequence: str, keyword: str) -> tuple[Optional[Dataset], str]:
        """``(item holding keyword, description)`` from the frame's group, else the shared group."""
        if frame < len(self.per_frame):
            item = _item(self.per_frame[frame], sequence)
            if _present(item, keyword):
                return item, f" in PerFrameFunctionalGroupsSequence[{frame}].{sequence}"
        item = _item(self.shared, sequence)
        if _present(item, keyword):
            return item, f" in SharedFunctionalGroupsSequence.{sequence}"
        return None, ""


def _check_range(path: Path, value: float, name: str, low: float, high: float, unit: str, where: str = "") -> float:
    if not low <= value <= high:
        raise DicomError(
            f"{path}: {name}{where} = {value:g} {unit} is not plausible; expected {low:g} to {high:g} {unit} "
            "(the file's header is damaged or uses another unit)"
        )
    return value


def _modality(path: Path, ds: Dataset) -> tuple[str, str]:
    modality = str(ds.get("Modality", "") or "")
    sop = str(ds.get("SOPClassUID", "") or "")
    if sop in _XA_CLASSES:
        if modality and modality not in _MODALITIES:
            raise DicomError(
                f"{path}: {_tag('Modality')} is {modality!r} but {_tag('SOPClassUID')} is {_XA_CLASSES[sop]} Image "
                f"Storage; an X-ray angiogram has Modality 'XA' (or 'RF'): the header contradicts itself, so its "
                f"geometry cannot be trusted")
        return modality or "XA", _XA_CLASSES[sop]
    if modality == "XA":
        return modality, "XA"
    meta = getattr(ds, "file_meta", None)
    stored = str(meta.get("MediaStorageSOPClassUID", "") or "") if meta is not None else ""
    if not modality and not sop and stored in _XA_CLASSES:
        raise DicomError(
            f"{path}: the data set cannot be read as {_transfer_syntax(ds)} ({_tag('TransferSyntaxUID')}): Modality and "
            f"SOPClassUID come out absent although {_tag('MediaStorageSOPClassUID')} says {_XA_CLASSES[stored]}; the "
            f"transfer syntax is probably mislabelled (or the file damaged)")
    try:
        sop_name = pydicom.uid.UID(sop).name if sop else "absent"
    except Exception:  # pragma: no cover - a malformed UID string
        sop_name = sop
    raise DicomError(
        f"{path}: is not an X-ray angiogram: {_tag('Modality')} is {modality or 'absent'!r} and "
        f"{_tag('SOPClassUID')} is {sop_name!r}; expected Modality 'XA' (X-Ray Angiographic Image Storage "
        "or Enhanced XA Image Storage), whose header holds the C-arm geometry"
    )


def _check_orientation(path: Path, ds: Dataset, groups: "_Groups", n_frames: int) -> None:
    """The stored image must face the detector as the geometry assumes, and the patient lie head first supine.

    FieldOfViewRotation (0018,7032) != 0 or FieldOfViewHorizontalFlip (0018,7034) = YES say the stored
    pixels were rotated or mirrored after acquisition (top level, or Enhanced XA's FieldOfViewSequence).
    Whether a file's angles refer to the detector or to the displayed image is not said by the
    standard in a way angiohull can check, so such a file is refused rather than reconstructed
    mirrored. PatientPosition (0018,5100) other than HFS is a warning: the angles are patient-relative,
    but the image's up and left on the detector then differ from the head-first-supine convention.
    """
    sources = [(ds, "")]
    if groups.enhanced:
        item = _item(groups.shared, "FieldOfViewSequence")
        if item is not None:
            sources.append((item, f" in SharedFunctionalGroupsSequence.{_tag('FieldOfViewSequence')}"))
        for frame in range(min(n_frames, len(groups.per_frame))):
            item = _item(groups.per_frame[frame], "FieldOfViewSequence")
            if item is not None:
                sources.append((item, f" in PerFrameFunctionalGroupsSequence[{frame}].{_tag('FieldOfViewSequence')}"))
    for container, where in sources:
        if _present(container, "FieldOfViewRotation"):
            rotation = _single(path, container, "FieldOfViewRotation", where)
            if rotation % 360 != 0:
                raise DicomError(
                    f"{path}: {_tag('FieldOfViewRotation')}{where} is {rotation:g} degrees: the stored image is rotated "
                    f"against the detector, and angiohull does not undo it (it cannot tell whether the C-arm angles refer "
                    f"to the detector or to the rotated image); export the run without rotation, or give the view as "
                    f"carm: with a mask in the detector's orientation")
        if _present(container, "FieldOfViewHorizontalFlip"):
            flip = str(container.FieldOfViewHorizontalFlip).strip().upper()
            if flip == "YES":
                raise DicomError(
                    f"{path}: {_tag('FieldOfViewHorizontalFlip')}{where} is YES: the stored image is mirrored against the "
                    f"detector, and angiohull does not undo it (a mirrored view reconstructs a mirrored or no vessel); "
                    f"export the run without the flip, or give the view as carm: with a mask in the detector's orientation")
            if flip != "NO":
                raise DicomError(f"{path}: {_tag('FieldOfViewHorizontalFlip')}{where} is {flip!r}; expected YES or NO")
    if _present(ds, "PatientPosition"):
        position = str(ds.PatientPosition).strip().upper()
        if position != "HFS":
            warnings.warn(
                f"{path}: {_tag('PatientPosition')} is {position!r}, not HFS (head first supine): angiohull reads the "
                f"C-arm geometry as for a patient lying head first supine, as in cardiac angiography; for {position} "
                f"the image's up and left may differ, and the reconstruction be mirrored or upside down: check it",
                InputWarning, stacklevel=3)


def _shape(path: Path, ds: Dataset) -> tuple[int, int, int]:
    for keyword in ("Rows", "Columns"):
        if not _present(ds, keyword):
            raise DicomError(f"{path}: {_tag(keyword)} is missing; an image needs its matrix size")
    rows, cols = int(ds.Rows), int(ds.Columns)
    if rows < 2 or cols < 2:
        raise DicomError(f"{path}: the image is {rows} x {cols} pixels ({_tag('Rows')}, {_tag('Columns')}); expected at least 2 x 2")
    frames = 1
    if _present(ds, "NumberOfFrames"):
        try:
            frames = int(ds.NumberOfFrames)
        except (TypeError, ValueError):
            raise DicomError(f"{path}: {_tag('NumberOfFrames')} is not an integer: {ds.NumberOfFrames!r}") from None
        if frames < 1:
            raise DicomError(f"{path}: {_tag('NumberOfFrames')} is {frames}; expected at least 1")
    if _present(ds, "SamplesPerPixel") and int(ds.SamplesPerPixel) != 1:
        raise DicomError(f"{path}: {_tag('SamplesPerPixel')} is {int(ds.SamplesPerPixel)}; an X-ray angiogram is grey-scale (1)")
    return rows, cols, frames


def _required(path: Path, keyword: str, what: str, enhanced_hint: str = "") -> DicomError:
    return DicomError(f"{path}: {_tag(keyword)} is missing{enhanced_hint}; it gives the {what}, which the "
                      "reconstruction needs (give the view's geometry as carm: in study.yaml instead)")


def _angles(path: Path, ds: Dataset, groups: _Groups, n_frames: int) -> tuple[list[tuple[float, float]], str]:
    """Per-frame (primary, secondary) angles and a description of where they came from."""
    if groups.enhanced:
        angles, sources = [], set()
        for frame in range(n_frames):
            pair = []
            for keyword in ("PositionerPrimaryAngle", "PositionerSecondaryAngle"):
                item, where = groups.find(frame, "PositionerPositionSequence", keyword)
                if item is None:
                    if _present(ds, keyword):  # some writers keep the classic attribute at the top level
                        item, where = ds, ""
                    else:
                        raise _required(path, keyword, "C-arm angle",
                                        f" for frame {frame} (looked in the per-frame and shared functional groups' "
                                        f"{_tag('PositionerPositionSequence')} and at the top level)")
                pair.append(_single(path, item, keyword, where))
                sources.add("per-frame functional groups" if "PerFrame" in where else "shared functional group" if where else "top level")
            angles.append((pair[0], pair[1]))
        return angles, "Enhanced XA " + " and ".join(sorted(sources)) + f" ({_tag('PositionerPositionSequence')})"
    base = []
    for keyword in ("PositionerPrimaryAngle", "PositionerSecondaryAngle"):
        if not _present(ds, keyword):
            raise _required(path, keyword, "C-arm angle")
        base.append(_single(path, ds, keyword))
    offsets = []
    used = []
    for keyword in ("PositionerPrimaryAngleIncrement", "PositionerSecondaryAngleIncrement"):
        if not _present(ds, keyword):
            offsets.append(np.zeros(n_frames))
            continue
        values = np.array(_numbers(path, ds, keyword))
        used.append(_tag(keyword))
        if values.size == 1:  # the average change per frame
            offsets.append(values[0] * np.arange(n_frames))
        elif values.size == n_frames:  # the offset of each frame from the run's angle
            offsets.append(values)
        else:
            raise DicomError(
                f"{path}: {_tag(keyword)} holds {values.size} values but the run has {n_frames} frames; "
                "expected one value (change per frame) or one per frame (PS3.3 C.8.7.5.1.3)"
            )
    angles = [(base[0] + float(offsets[0][i]), base[1] + float(offsets[1][i])) for i in range(n_frames)]
    source = f"{_tag('PositionerPrimaryAngle')}, {_tag('PositionerSecondaryAngle')}"
    if used:
        source += " + per-frame increments " + ", ".join(used)
    return angles, source


def _distance(path: Path, ds: Dataset, groups: _Groups, frame: int, keywords: Sequence[str], what: str) -> float:
    """A distance from the frame's X-Ray Geometry group (Enhanced) or the top level."""
    if groups.enhanced:
        for keyword in keywords:
            item, where = groups.find(frame, "XRayGeometrySequence", keyword)
            if item is not None:
                return _single(path, item, keyword, where)
    for keyword in keywords:
        if _present(ds, keyword):
            return _single(path, ds, keyword)
    names = " or ".join(_tag(k) for k in keywords)
    raise DicomError(f"{path}: {names} is missing; it gives the {what}, which the reconstruction needs "
                     "(give the view's geometry as carm: in study.yaml instead)")


def _spacing(path: Path, ds: Dataset, groups: _Groups, frame: int, rows: int, cols: int) -> tuple[tuple[float, float], str, Optional[str]]:
    """``(spacing, source, warning or None)`` for one frame."""
    item, where = (groups.find(frame, "FramePixelDataPropertiesSequence", "ImagerPixelSpacing") if groups.enhanced else (None, ""))
    if item is None and _present(ds, "ImagerPixelSpacing"):
        item, where = ds, ""
    if item is not None:
        values = _numbers(path, item, "ImagerPixelSpacing", where)
        if len(values) != 2:
            raise DicomError(f"{path}: {_tag('ImagerPixelSpacing')}{where} must hold 2 numbers (row, column spacing in mm), got {values}")
        return (values[0], values[1]), _tag("ImagerPixelSpacing") + where, None
    missing = f"{_tag('ImagerPixelSpacing')} is missing"
    fov_item, fov_where, fov_keyword = None, "", "FieldOfViewDimensions"
    if groups.enhanced:
        fov_item, fov_where = groups.find(frame, "FieldOfViewSequence", "FieldOfViewDimensionsInFloat")
        fov_keyword = "FieldOfViewDimensionsInFloat" if fov_item is not None else fov_keyword
    if fov_item is None and _present(ds, "FieldOfViewDimensions"):
        fov_item, fov_where, fov_keyword = ds, "", "FieldOfViewDimensions"
    if fov_item is not None:
        fov = _numbers(path, fov_item, fov_keyword, fov_where)
        if len(fov) == 2:  # RECTANGLE: row dimension, column dimension
            spacing = (fov[0] / rows, fov[1] / cols)
            how = f"{_tag(fov_keyword)}{fov_where} = [{fov[0]:g}, {fov[1]:g}] mm over {rows} x {cols} pixels"
        elif len(fov) == 1:  # ROUND or HEXAGONAL: a diameter across the larger matrix side
            spacing = (fov[0] / max(rows, cols),) * 2
            how = f"{_tag(fov_keyword)}{fov_where} = {fov[0]:g} mm (diameter) over {max(rows, cols)} pixels"
        else:
            raise DicomError(f"{path}: {_tag(fov_keyword)}{fov_where} must hold 1 or 2 numbers (mm), got {fov}")
        return spacing, how, f"{path}: {missing}; assumed {spacing[0]:g} x {spacing[1]:g} mm from {how}"
    if _present(ds, "IntensifierSize"):
        size = _single(path, ds, "IntensifierSize")
        spacing = (size / max(rows, cols),) * 2
        how = f"{_tag('IntensifierSize')} = {size:g} mm over {max(rows, cols)} pixels"
        return spacing, how, (f"{path}: {missing} and so is {_tag('FieldOfViewDimensions')}; assumed "
                              f"{spacing[0]:g} x {spacing[1]:g} mm from {how} (the intensifier's diameter, "
                              "an approximation of the field of view)")
    raise DicomError(
        f"{path}: {missing}, and neither {_tag('FieldOfViewDimensions')} nor {_tag('IntensifierSize')} is there to "
        "derive it from; the pixel spacing at the detector is needed (give the view's geometry as carm: in study.yaml)"
    )


def _frame_times(path: Path, ds: Dataset, n_frames: int) -> Optional[np.ndarray]:
    if _present(ds, "FrameTimeVector"):
        steps = np.array(_numbers(path, ds, "FrameTimeVector"))
        if steps.size != n_frames:
            raise DicomError(f"{path}: {_tag('FrameTimeVector')} holds {steps.size} values but the run has {n_frames} frames")
        return np.cumsum(steps) - steps[0]  # the first value is the (zero) increment of the first frame
    if _present(ds, "FrameTime"):
        return _single(path, ds, "FrameTime") * np.arange(n_frames)
    return None


def _end_diastole(path: Path, ds: Dataset, groups: _Groups, n_frames: int, times: Optional[np.ndarray]) -> tuple[tuple[int, ...], Optional[str]]:
    if groups.per_frame:
        marked = [i for i in range(n_frames)
                  if str((_item(groups.per_frame[i], "FrameContentSequence") or Dataset()).get("CardiacCyclePosition", "")) == "END_DIASTOLE"]
        if marked:
            return tuple(marked), f"{_tag('CardiacCyclePosition')} in the per-frame {_tag('FrameContentSequence')}"
    if _present(ds, "RWavePointer"):
        numbers = [int(v) for v in _numbers(path, ds, "RWavePointer")]
        bad = [n for n in numbers if not 1 <= n <= n_frames]
        if bad:
            raise DicomError(f"{path}: {_tag('RWavePointer')} names frame number(s) {bad} but the run has frames 1 to {n_frames}")
        return tuple(sorted({n - 1 for n in numbers})), _tag("RWavePointer")
    if _present(ds, "RWaveTimeVector") and times is not None:
        r_times = np.array(_numbers(path, ds, "RWaveTimeVector"))
        step = float(np.median(np.diff(times))) if n_frames > 1 else 0.0
        inside = r_times[(r_times >= times[0] - step) & (r_times <= times[-1] + step)]
        nearest = {int(np.argmin(np.abs(times - t))) for t in inside}
        source = f"{_tag('RWaveTimeVector')} and " + (_tag("FrameTimeVector") if _present(ds, "FrameTimeVector") else _tag("FrameTime"))
        return tuple(sorted(nearest)), source
    return (), None


def _transfer_syntax(ds: Dataset) -> str:
    meta = getattr(ds, "file_meta", None)
    uid = meta.get("TransferSyntaxUID", None) if meta is not None else None
    return uid.name if uid is not None else "unknown"


def read_xa_header(path: PathLike) -> XAHeader:
    """Read the geometry and frame information of an XA file (pixel data are not read).

    Parameters
    ----------
    path : str or Path
        A DICOM file of modality XA (X-Ray Angiographic or Enhanced XA Image Storage).

    Returns
    -------
    XAHeader

    Warns
    -----
    DicomGeometryWarning
        When the pixel spacing is derived from FieldOfViewDimensions or IntensifierSize (once per
        file and source).
    InputWarning
        When PatientPosition (0018,5100) is not HFS, or pydicom had to guess or repair something
        while reading (e.g. a transfer syntax that says implicit VR for an explicit-VR data set);
        the message names the file and the tag.

    Raises
    ------
    DicomError
        Not a DICOM file, not an XA image, a Modality other than XA/RF in an XA file, a header
        that cannot be read as its transfer syntax (mislabelled), an element that cannot be
        decoded (e.g. a damaged value representation), a missing angle, distance, matrix size or
        spacing (with no fallback), values that are not numbers, implausible values (SID outside
        200-3000 mm, SOD >= SID, spacing outside 0.01-5 mm, angles outside [-180, 180] /
        [-90, 90]), increment vectors of the wrong length, or a stored image rotated or mirrored
        against the detector (FieldOfViewRotation (0018,7032) != 0, FieldOfViewHorizontalFlip
        (0018,7034) YES: refused, not undone). The message names the file and the tag.
    """
    path = Path(path)
    caught: list = []
    ds = _read_dataset(path, pixels=False, caught=caught)
    modality, sop_class = _modality(path, ds)
    rows, cols, n_frames = _shape(path, ds)
    # what pydicom had to repair or guess, once the header has proved to be an XA header
    _pydicom_warnings(path, caught, f"the data set, read as its {_tag('TransferSyntaxUID')} {_transfer_syntax(ds)} says")
    groups = _Groups(ds)
    _check_orientation(path, ds, groups, n_frames)
    if groups.enhanced and groups.per_frame and len(groups.per_frame) != n_frames:
        raise DicomError(f"{path}: PerFrameFunctionalGroupsSequence (5200,9230) has {len(groups.per_frame)} items but "
                         f"{_tag('NumberOfFrames')} is {n_frames}")
    angles, angle_source = _angles(path, ds, groups, n_frames)
    sod_keywords = ("DistanceSourceToIsocenter", "DistanceSourceToPatient") if groups.enhanced else ("DistanceSourceToPatient",)
    frames, warned, spacing_sources = [], [], []
    for index in range(n_frames):
        sid = _distance(path, ds, groups, index, ("DistanceSourceToDetector",), "source-to-detector distance (SID)")
        sod = _distance(path, ds, groups, index, sod_keywords, "source-to-isocentre distance (SOD)")
        spacing, spacing_source, warning = _spacing(path, ds, groups, index, rows, cols)
        where = f" (frame {index})" if n_frames > 1 else ""
        _check_range(path, sid, "the SID " + _tag("DistanceSourceToDetector"), *SID_RANGE_MM, "mm", where)
        if not SOD_MIN_MM <= sod < sid:
            raise DicomError(
                f"{path}: the SOD {' or '.join(_tag(k) for k in sod_keywords)}{where} = {sod:g} mm is not plausible "
                f"with the SID = {sid:g} mm; expected {SOD_MIN_MM:g} mm <= SOD < SID (the isocentre lies between "
                "source and detector)"
            )
        for value in spacing:
            _check_range(path, value, f"the pixel spacing (from {spacing_source})", *SPACING_RANGE_MM, "mm", where)
        primary, secondary = angles[index]
        _check_range(path, primary, "the primary angle " + _tag("PositionerPrimaryAngle"), -180.0, 180.0, "degrees", where)
        _check_range(path, secondary, "the secondary angle " + _tag("PositionerSecondaryAngle"), -90.0, 90.0, "degrees", where)
        if warning is not None and warning not in warned:
            warned.append(warning)
        if spacing_source not in spacing_sources:
            spacing_sources.append(spacing_source)
        frames.append(XAFrameGeometry(index, primary, secondary, sid, sod, spacing, (rows, cols)))
    for warning in warned:
        warnings.warn(warning, DicomGeometryWarning, stacklevel=2)
    times = _frame_times(path, ds, n_frames)
    end_diastolic, ecg_source = _end_diastole(path, ds, groups, n_frames, times)
    return XAHeader(
        path=path, modality=modality, sop_class=sop_class, n_frames=n_frames, image_shape=(rows, cols),
        frames=tuple(frames), angle_source=angle_source, spacing_source="; ".join(spacing_sources),
        end_diastolic_frames=end_diastolic, ecg_source=ecg_source,
        frame_times_ms=None if times is None else tuple(float(t) for t in times),
        transfer_syntax=_transfer_syntax(ds), photometric=str(ds.get("PhotometricInterpretation", "") or ""),
        sop_instance_uid=str(ds.get("SOPInstanceUID", "") or ""),
    )


# -- pixel data --------------------------------------------------------------------------------
_PLUGIN_HINTS = {
    "JPEG 2000": "pip install pylibjpeg pylibjpeg-openjpeg (or python-gdcm)",
    "High-Throughput JPEG 2000": "pip install pylibjpeg pylibjpeg-openjpeg",
    "JPEG-LS": "pip install pyjpegls (or python-gdcm)",
    "JPEG": "pip install pylibjpeg pylibjpeg-libjpeg (or python-gdcm)",
    "RLE": "pip install pylibjpeg pylibjpeg-rle (or use pydicom's own RLE decoder)",
}


def _install_hint(syntax_name: str) -> str:
    for key in ("High-Throughput JPEG 2000", "JPEG 2000", "JPEG-LS", "JPEG", "RLE"):
        if key.replace("-", "").replace(" ", "").lower() in syntax_name.replace("-", "").replace(" ", "").lower():
            return _PLUGIN_HINTS[key]
    return "pip install pylibjpeg pylibjpeg-libjpeg pylibjpeg-openjpeg (or python-gdcm)"


def _decoder_status(uid: Any) -> tuple[bool, list[str]]:
    """Whether pydicom can decode this transfer syntax here, and what it says is missing."""
    try:
        decoder = pydicom.pixels.get_decoder(uid)
    except NotImplementedError:
        return False, ["no pydicom decoder exists for this transfer syntax"]
    return bool(decoder.is_available), list(decoder.missing_dependencies)


def _decode(path: Path, ds: Dataset, header: XAHeader, index: Optional[int]) -> np.ndarray:
    if "PixelData" not in ds and "FloatPixelData" not in ds and "DoubleFloatPixelData" not in ds:
        raise DicomError(f"{path}: has no pixel data (7FE0,0010)")
    uid = ds.file_meta.get("TransferSyntaxUID", None) if getattr(ds, "file_meta", None) is not None else None
    if uid is not None and uid.is_compressed:
        available, missing = _decoder_status(uid)
        if not available:
            raise DicomError(
                f"{path}: cannot decode the pixel data: transfer syntax {uid.name} ({uid}) needs a decoder plugin "
                f"that is not installed; install one: {_install_hint(uid.name)} (pydicom reports: {'; '.join(missing)})"
            )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            array = ds.pixel_array if index is None else pydicom.pixels.pixel_array(ds, index=index)
        except Exception as exc:  # decoders raise many types; all mean the same to the user
            name = uid.name if uid is not None else "unknown"
            detail = " ".join(str(exc).split())  # one line
            raise DicomError(
                f"{path}: cannot decode the pixel data (transfer syntax {name}): {type(exc).__name__}: {detail}; the file may "
                "be damaged or truncated"
            ) from None
    _pydicom_warnings(path, caught, f"{_tag('PixelData')} ({uid.name if uid is not None else 'unknown transfer syntax'})")
    rows, cols = header.image_shape
    expected = (rows, cols) if index is not None or header.n_frames == 1 else (header.n_frames, rows, cols)
    if array.shape != expected:
        raise DicomError(f"{path}: decoded pixel data have shape {array.shape}, expected {expected} from the header")
    if header.photometric == "MONOCHROME1":  # higher values = less X-ray intensity: invert
        bits = int(ds.get("BitsStored", array.dtype.itemsize * 8))
        if array.dtype.kind == "u":
            array = ((1 << bits) - 1) - array
        else:
            array = array.max() - array
    return array


def read_xa_frames(path: PathLike, header: Optional[XAHeader] = None) -> np.ndarray:
    """Decode every frame of an XA file.

    Parameters
    ----------
    path : str or Path
        The file.
    header : XAHeader, optional
        Its header, when already read (avoids reading it again and repeating its warnings).

    Returns
    -------
    frames : ndarray, shape (n_frames, rows, cols)
        As stored (uint8/uint16), MONOCHROME1 inverted so that brighter = more intensity.

    Raises
    ------
    DicomError
        As :func:`read_xa_header`, and when the pixel data cannot be decoded: a missing decoder
        plugin (the message says which to install), damaged data, or a shape that differs from
        the header's.
    """
    path = Path(path)
    header = read_xa_header(path) if header is None else header
    ds = _read_dataset(path, pixels=True)
    array = _decode(path, ds, header, None)
    return array.reshape((header.n_frames, *header.image_shape))


def read_xa_frame(path: PathLike, frame: int, header: Optional[XAHeader] = None) -> np.ndarray:
    """Decode one frame (index from 0) of an XA file; shape (rows, cols). See :func:`read_xa_frames`."""
    path = Path(path)
    header = read_xa_header(path) if header is None else header
    index = header.check_frame(frame)
    ds = _read_dataset(path, pixels=True)
    return _decode(path, ds, header, index if header.n_frames > 1 else None)


# -- frame selection ---------------------------------------------------------------------------
def select_frame(frames: Any, *, end_diastolic_frames: Sequence[int] = (), parameters: Any = None) -> FrameSelection:
    """Pick the frame of a run to reconstruct from.

    Parameters
    ----------
    frames : array_like, shape (n_frames, rows, cols)
        The decoded run.
    end_diastolic_frames : sequence of int
        Frames known to be end-diastolic (from the ECG data of the file, :class:`XAHeader`).
    parameters : SegmentationParameters, optional
        Polarity and collimator settings for the contrast score.

    Returns
    -------
    FrameSelection
        The frame with the highest :func:`~angiohull.segmentation.vessel_contrast_score`; with
        end-diastolic frames given, the end-diastolic frame nearest to it (ties: the higher score).
    """
    from .segmentation import vessel_contrast_score

    array = np.asarray(frames)
    if array.ndim != 3 or array.shape[0] < 1:
        raise DicomError(f"frames must be an (n_frames, rows, cols) array, got shape {array.shape}")
    n = array.shape[0]
    ed = sorted({int(i) for i in end_diastolic_frames})
    if any(not 0 <= i < n for i in ed):
        raise DicomError(f"end_diastolic_frames must be indices 0 to {n - 1}, got {ed}")
    if n == 1:
        return FrameSelection(0, "single frame", end_diastolic_frames=tuple(ed))
    scores = np.array([vessel_contrast_score(frame, parameters) for frame in array])
    best = int(np.argmax(scores))
    if not ed:
        return FrameSelection(best, f"most contrast (frame {best} of {n})", tuple(float(s) for s in scores), best, ())
    chosen = min(ed, key=lambda i: (abs(i - best), -scores[i]))
    reason = f"end-diastolic frame nearest to the most-contrast frame {best} (end-diastolic: {ed})"
    return FrameSelection(chosen, reason, tuple(float(s) for s in scores), best, tuple(ed))


def read_xa_view(path: PathLike, frame: Optional[int] = None, *, parameters: Any = None,
                 header: Optional[XAHeader] = None) -> XAView:
    """Read one frame of an XA file with its geometry: the DICOM input of a view.

    Parameters
    ----------
    path : str or Path
        The XA file.
    frame : int, optional
        Frame index from 0. Default: the only frame of a single-frame file, else chosen by
        :func:`select_frame` (most contrast, or the end-diastolic frame nearest to it).
    parameters : SegmentationParameters, optional
        Settings of the contrast score used for automatic selection.
    header : XAHeader, optional
        The file's header, when already read (avoids reading it again and repeating its warnings).

    Returns
    -------
    XAView
        The frame's image, its :class:`~angiohull.geometry.CArmGeometry` and the header.

    Raises
    ------
    DicomError
        See :func:`read_xa_header` and :func:`read_xa_frames`.
    """
    path = Path(path)
    header = read_xa_header(path) if header is None else header
    if frame is not None:
        index = header.check_frame(frame)
        image = read_xa_frame(path, index, header)
        selection = FrameSelection(index, f"frame {index} as requested", end_diastolic_frames=header.end_diastolic_frames)
    elif header.n_frames == 1:
        image = read_xa_frame(path, 0, header)
        selection = FrameSelection(0, "single frame")
    else:
        frames = read_xa_frames(path, header)
        selection = select_frame(frames, end_diastolic_frames=header.end_diastolic_frames, parameters=parameters)
        image = frames[selection.frame]
    try:
        carm = header.frames[selection.frame].carm()
    except GeometryError as exc:  # pragma: no cover - the ranges are checked when reading the header
        raise DicomError(f"{path}: {exc}") from None
    return XAView(header=header, frame=selection.frame, image=image, carm=carm, selection=selection)
