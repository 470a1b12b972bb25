"""Synthetic XA DICOM files for the tests, written with pydicom (and a tiny JPEG Lossless encoder).

pydicom has no encoder for JPEG Lossless, Non-Hierarchical, First-Order Prediction (Process 14,
Selection Value 1), the transfer syntax of most cardiac archives, so :func:`jpeg_lossless_sv1`
writes one from ITU-T T.81 Annex H: predictor 1 (the left neighbour; the row above for the first
column; 2**(P-1) for the very first sample), one Huffman table giving every difference category
SSSS = 0..16 a 5-bit code, the SSSS low bits of the difference (minus one when negative) after
each code, 0xFF bytes stuffed with 0x00. The decoder under test (pylibjpeg-libjpeg) is independent
of it: a round trip that returns the input pixels checks both.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydicom.dataset import Dataset, FileMetaDataset
from pydicom.encaps import encapsulate
from pydicom.uid import ExplicitVRLittleEndian, JPEGLosslessSV1, generate_uid

XA = "1.2.840.10008.5.1.4.1.1.12.1"
ENHANCED_XA = "1.2.840.10008.5.1.4.1.1.12.1.1"
CT = "1.2.840.10008.5.1.4.1.1.2"


def _bits_msb_first(values: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Concatenate ``values[i]`` written on ``lengths[i]`` bits (MSB first) into one bit array."""
    width = int(lengths.max()) if lengths.size else 0
    k = np.arange(width)
    shifts = lengths[:, None] - 1 - k[None, :]
    bits = (values[:, None] >> np.maximum(shifts, 0)) & 1
    return bits[shifts >= 0].astype(np.uint8)


def jpeg_lossless_sv1(image: np.ndarray, bits_stored: int) -> bytes:
    """Encode a grey-scale image as a JPEG Lossless SV1 (process 14, predictor 1) codestream."""
    x = np.asarray(image).astype(np.int64)
    rows, cols = x.shape
    pred = np.empty_like(x)
    pred[0, 0] = 1 << (bits_stored - 1)
    pred[0, 1:] = x[0, :-1]
    pred[1:, 0] = x[:-1, 0]
    pred[1:, 1:] = x[1:, :-1]
    diff = (x - pred) % 65536
    diff[diff >= 32768] -= 65536
    diff = diff.ravel()
    magnitude = np.abs(diff)
    ssss = np.zeros(diff.size, dtype=np.int64)
    nonzero = magnitude > 0
    ssss[nonzero] = np.floor(np.log2(magnitude[nonzero])).astype(np.int64) + 1
    extra_len = np.where(ssss == 16, 0, ssss)
    extra = np.where(diff >= 0, diff, diff - 1) & ((1 << extra_len) - 1)
    codes = (ssss << extra_len) | extra  # the 5-bit Huffman code of SSSS is SSSS itself
    bitstream = _bits_msb_first(codes, 5 + extra_len)
    pad = (-bitstream.size) % 8
    bitstream = np.concatenate([bitstream, np.ones(pad, np.uint8)])
    data = np.packbits(bitstream).tobytes().replace(b"\xff", b"\xff\x00")
    sof = b"\xff\xc3" + (11).to_bytes(2, "big") + bytes([bits_stored]) + rows.to_bytes(2, "big") + cols.to_bytes(2, "big") \
        + bytes([1, 1, 0x11, 0])
    counts = [0, 0, 0, 0, 17] + [0] * 11
    dht = b"\xff\xc4" + (2 + 1 + 16 + 17).to_bytes(2, "big") + bytes([0x00]) + bytes(counts) + bytes(range(17))
    sos = b"\xff\xda" + (8).to_bytes(2, "big") + bytes([1, 1, 0x00, 1, 0, 0])
    return b"\xff\xd8" + sof + dht + sos + data + b"\xff\xd9"


def write_xa(
    path: Path,
    pixels: np.ndarray,
    *,
    primary: float | None = 31.3,
    secondary: float | None = -12.5,
    sid: float | None = 1100.0,
    sod: float | None = 760.0,
    spacing: tuple[float, float] | None = (0.3, 0.3),
    compressed: bool = False,
    sop_class: str = XA,
    modality: str = "XA",
    photometric: str = "MONOCHROME2",
    **extra,
) -> Path:
    """Write a (multi-frame) XA file; geometry attributes given as None are left out.

    ``pixels`` is (rows, cols) or (frames, rows, cols), uint8 or uint16. ``extra`` sets further
    attributes by keyword (a value of None deletes one).
    """
    pixels = np.asarray(pixels)
    frames = pixels[None] if pixels.ndim == 2 else pixels
    n, rows, cols = frames.shape
    bits = 8 if frames.dtype == np.uint8 else 16
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop_class
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = JPEGLosslessSV1 if compressed else ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = sop_class
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.StudyInstanceUID = generate_uid()
    ds.SeriesInstanceUID = generate_uid()
    ds.Modality = modality
    ds.PatientName = "Synthetic^Phantom"
    ds.PatientID = "angiohull-test"
    for keyword, value in (("PositionerPrimaryAngle", primary), ("PositionerSecondaryAngle", secondary),
                           ("DistanceSourceToDetector", sid), ("DistanceSourceToPatient", sod),
                           ("ImagerPixelSpacing", None if spacing is None else list(spacing))):
        if value is not None:
            setattr(ds, keyword, value)
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = photometric
    ds.Rows, ds.Columns = rows, cols
    ds.BitsAllocated = bits
    ds.BitsStored = bits
    ds.HighBit = bits - 1
    ds.PixelRepresentation = 0
    if pixels.ndim == 3:
        ds.NumberOfFrames = n
    for keyword, value in extra.items():
        if value is None:
            if keyword in ds:
                delattr(ds, keyword)
        else:
            setattr(ds, keyword, value)
    if compressed:
        ds.PixelData = encapsulate([jpeg_lossless_sv1(frame, bits) for frame in frames])
        ds["PixelData"].VR = "OB"
        ds["PixelData"].is_undefined_length = True
    else:
        ds.PixelData = np.ascontiguousarray(frames.astype("<u1" if bits == 8 else "<u2")).tobytes()
        ds["PixelData"].VR = "OB" if bits == 8 else "OW"
    ds.save_as(path, enforce_file_format=True)
    return Path(path)


def enhanced_groups(frames: list[dict], shared: dict | None = None) -> dict:
    """PerFrame/SharedFunctionalGroupsSequence of an Enhanced XA file.

    Each dict may hold ``primary``, ``secondary`` (PositionerPositionSequence), ``sid``,
    ``sod`` (XRayGeometrySequence: DistanceSourceToDetector, DistanceSourceToIsocenter),
    ``spacing`` (FramePixelDataPropertiesSequence.ImagerPixelSpacing), ``cycle``
    (FrameContentSequence.CardiacCyclePosition).
    """

    def group(values: dict) -> Dataset:
        item = Dataset()
        if "primary" in values or "secondary" in values:
            pos = Dataset()
            if "primary" in values:
                pos.PositionerPrimaryAngle = values["primary"]
            if "secondary" in values:
                pos.PositionerSecondaryAngle = values["secondary"]
            item.PositionerPositionSequence = [pos]
        if "sid" in values or "sod" in values:
            geo = Dataset()
            if "sid" in values:
                geo.DistanceSourceToDetector = values["sid"]
            if "sod" in values:
                geo.DistanceSourceToIsocenter = values["sod"]
            item.XRayGeometrySequence = [geo]
        if "spacing" in values:
            props = Dataset()
            props.ImagerPixelSpacing = list(values["spacing"])
            item.FramePixelDataPropertiesSequence = [props]
        if "cycle" in values:
            content = Dataset()
            content.CardiacCyclePosition = values["cycle"]
            item.FrameContentSequence = [content]
        return item

    out = {"PerFrameFunctionalGroupsSequence": [group(v) for v in frames]}
    if shared is not None:
        out["SharedFunctionalGroupsSequence"] = [group(shared)]
    return out
