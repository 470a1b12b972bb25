"""Mask corruptions: each changes exactly what its record says; specs and records round-trip."""

import numpy as np
import pytest
from scipy import ndimage as ndi

from angiohull.errors import AngiohullError
from angiohull.synthetic.corruptions import (CatheterStroke, CorruptionSpec, FalseNegatives, FalsePositives,
                                             MissingSegment, Rotate, Scale, SpuriousBlob, Translate, apply_all,
                                             corruption_from_dict, draw_corruptions, parse_corruption)


@pytest.fixture
def mask():
    rng = np.random.default_rng(0)
    m = rng.random((41, 53)) < 0.2
    m[:3] = m[-3:] = False
    m[:, :3] = m[:, -3:] = False
    return m


def _vessel():
    m = np.zeros((64, 64), dtype=bool)
    m[30:34, 8:56] = True  # a horizontal vessel, 4 px wide
    m[10:56, 40:43] = True  # and a vertical one
    return m


def _shift(m, tx, ty):
    """Oracle: content moved by integer (tx, ty) with background entering (pixel by pixel)."""
    out = np.zeros_like(m)
    rows, cols = m.shape
    for r, c in zip(*np.nonzero(m)):
        if 0 <= r + ty < rows and 0 <= c + tx < cols:
            out[r + ty, c + tx] = True
    return out


@pytest.mark.parametrize("tx, ty", [(0, 0), (5, 0), (0, -7), (-3, 4), (60, 0)])
def test_integer_translation_is_an_exact_shift(mask, tx, ty):
    assert np.array_equal(Translate(tx, ty).apply(mask), _shift(mask, tx, ty))


def test_fractional_translation_takes_the_nearest_source_pixel(mask):
    # Output u samples input u - 2.4, whose nearest pixel is u - 2 (and v + 3.6 -> v + 4).
    assert np.array_equal(Translate(2.4, -3.6).apply(mask), _shift(mask, 2, -4))


def test_rotation_by_90_degrees_turns_clockwise_as_displayed():
    square = np.random.default_rng(1).random((31, 31)) < 0.3
    assert np.array_equal(Rotate(90).apply(square), np.rot90(square, k=-1))
    assert np.array_equal(Rotate(0).apply(square), square)


def test_scaling_by_two_maps_offset_k_to_2k():
    m = np.random.default_rng(2).random((33, 33)) < 0.3
    out = Scale(2.0).apply(m)
    k = np.arange(-8, 9)
    # Centre (16, 16): output offset 2k samples input offset exactly k.
    assert np.array_equal(out[np.ix_(16 + 2 * k, 16 + 2 * k)], m[np.ix_(16 + k, 16 + k)])
    assert np.array_equal(Scale(1.0).apply(m), m)


def test_false_positives_flip_exactly_the_recorded_pattern(mask):
    record = FalsePositives(0.05, seed=1234)
    out = record.apply(mask)
    pattern = np.random.default_rng(1234).random(mask.shape) < 0.05
    assert np.array_equal(out & ~mask, pattern & ~mask)  # background -> vessel where drawn
    assert np.array_equal(out & mask, mask)  # no vessel pixel lost
    assert np.array_equal(record.apply(mask), out)  # replay


def test_false_negatives_flip_exactly_the_recorded_pattern(mask):
    record = FalseNegatives(0.3, seed=99)
    out = record.apply(mask)
    pattern = np.random.default_rng(99).random(mask.shape) < 0.3
    assert np.array_equal(mask & ~out, mask & pattern)
    assert not (out & ~mask).any()
    # About p of the vessel pixels go (binomial: 3 standard deviations).
    n = mask.sum()
    assert abs((mask & ~out).sum() - 0.3 * n) < 3 * np.sqrt(n * 0.3 * 0.7)


@pytest.mark.parametrize("p", [0.0, 1.0])
def test_noise_extremes(mask, p):
    assert np.array_equal(FalsePositives(p, 5).apply(mask), mask if p == 0 else np.ones_like(mask))
    assert np.array_equal(FalseNegatives(p, 5).apply(mask), mask if p == 0 else np.zeros_like(mask))


def test_missing_segment_erases_the_recorded_disk_only():
    m = _vessel()
    record = MissingSegment((31.5, 20.0), 6.0)
    out = record.apply(m)
    rr, cc = np.mgrid[0:64, 0:64]
    disk = (rr - 31.5) ** 2 + (cc - 20.0) ** 2 <= 36.0
    assert np.array_equal(m & ~out, m & disk)
    assert not (out & ~m).any()
    # The horizontal vessel is cut in two.
    assert ndi.label(out[28:36])[1] == 2


def test_blob_adds_the_recorded_ellipse_only():
    m = _vessel()
    record = SpuriousBlob((12.0, 15.0), (6.0, 3.0), 0.0)
    out = record.apply(m)
    rr, cc = np.mgrid[0:64, 0:64]
    ellipse = ((cc - 15.0) / 6.0) ** 2 + ((rr - 12.0) / 3.0) ** 2 <= 1.0
    assert np.array_equal(out & ~m, ellipse & ~m)
    assert np.array_equal(out & m, m)


def test_catheter_adds_a_stroke_of_the_recorded_width_along_the_curve():
    m = _vessel()
    record = CatheterStroke(((0.0, 5.0), (20.0, 5.0), (40.0, 5.0)), 5.0)  # a straight vertical line, col 5
    out = record.apply(m)
    added = out & ~m
    rows, cols = np.nonzero(added)
    assert np.abs(cols - 5).max() <= 2.5 and set(range(0, 41)) <= set(rows.tolist())
    assert np.array_equal(out & m, m)


def test_records_round_trip_through_dicts():
    records = [Translate(3.5, -1.0), Scale(1.2), Rotate(4.0), FalsePositives(0.01, 7), FalseNegatives(0.2, 8),
               MissingSegment((10.0, 12.0), 5.0), SpuriousBlob((3.0, 4.0), (5.0, 2.0), 30.0),
               CatheterStroke(((0.0, 1.0), (2.0, 3.0), (4.0, 5.0)), 6.0)]
    for record in records:
        assert corruption_from_dict(record.to_dict()) == record


def test_drawing_is_seeded_and_looks_at_the_mask():
    masks = [_vessel(), _vessel()]
    specs = [parse_corruption("missing=2"), parse_corruption("fp=0.01"), parse_corruption("translate=4,5")]
    a = draw_corruptions(specs, masks, 11)
    b = draw_corruptions(specs, masks, np.random.default_rng(11))
    assert a == b
    assert [r.kind for r in a[0]] == ["missing", "missing", "fp", "translate"]  # translate: view 0 only
    assert [r.kind for r in a[1]] == ["missing", "missing", "fp"]
    for record in a[0][:2]:  # a missing segment is centred on the vessel
        assert masks[0][int(record.centre_rc[0]), int(record.centre_rc[1])]
    out = apply_all(masks[0], a[0])
    assert np.array_equal(out, a[0][3].apply(a[0][2].apply(a[0][1].apply(a[0][0].apply(masks[0])))))


@pytest.mark.parametrize("text, views", [
    ("translate=10,0", None), ("scale=1.1@2", (2,)), ("fp=0.01@all", "all"), ("missing=2@0,1", (0, 1)),
    ("rotate=-3", None), ("catheter=1", None),
])
def test_spec_syntax(text, views):
    spec = parse_corruption(text)
    assert spec.views == views


def test_view_selection_defaults():
    assert parse_corruption("translate=1,1").view_indices(3) == (0,)
    assert parse_corruption("translate=1,1@all").view_indices(3) == (0, 1, 2)
    assert parse_corruption("fn=0.1").view_indices(3) == (0, 1, 2)
    with pytest.raises(AngiohullError, match="out of range"):
        parse_corruption("fn=0.1@3").view_indices(3)


@pytest.mark.parametrize("text, message", [
    ("fp=1.5", r"p must lie in \[0, 1\]"),
    ("fn=-0.1", r"p must lie in \[0, 1\]"),
    ("translate=3", "expected 2"),
    ("scale=0", "factor must be > 0"),
    ("missing=1.5", "whole number"),
    ("blur=3", "unknown kind"),
    ("fp", "cannot read"),
    ("fp=abc", "as numbers"),
])
def test_bad_specs_say_what_is_wrong(text, message):
    with pytest.raises(AngiohullError, match=message):
        parse_corruption(text)


def test_bad_record_kind():
    with pytest.raises(AngiohullError, match="kind must be one of"):
        corruption_from_dict({"kind": "smudge"})
    with pytest.raises(AngiohullError, match="translate"):
        CorruptionSpec("translate", (1.0, float("nan")))
