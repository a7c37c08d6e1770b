from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from runtime.decision.patterns import (
    BUILTIN_PATTERNS,
    PatternError,
    make_pattern,
    min_spacing,
    resample_polyline,
)
from runtime.world_config import DEFAULT_WORLD


@pytest.mark.parametrize("name", BUILTIN_PATTERNS)
@pytest.mark.parametrize("n", [2, 3, 4, 7, 10, 13, 20, 50])
def test_builtins_have_default_spacing_and_are_centred(name: str, n: int) -> None:
    p = make_pattern(name, n)
    assert p.shape == (n, 2)
    assert np.isfinite(p).all()
    assert min_spacing(p) == pytest.approx(DEFAULT_WORLD.pattern_spacing_m, rel=1e-9)
    assert np.allclose(p.mean(0), 0.0, atol=1e-12)


def test_circle_is_a_regular_polygon() -> None:
    p = make_pattern("circle", 12)
    r = np.linalg.norm(p, axis=1)
    assert np.allclose(r, r[0])
    chords = np.linalg.norm(p - np.roll(p, 1, axis=0), axis=1)
    assert np.allclose(chords, DEFAULT_WORLD.pattern_spacing_m)


def test_line_is_evenly_spaced_on_one_axis() -> None:
    p = make_pattern("line", 9)
    assert np.allclose(p[:, 1], 0.0)
    assert np.allclose(np.diff(np.sort(p[:, 0])), DEFAULT_WORLD.pattern_spacing_m)


def test_resample_closed_polyline_by_arc_length() -> None:
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    pts = resample_polyline(square, 8, closed=True)
    gaps = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
    assert np.allclose(gaps, 0.5)


def test_csv_and_json_files(tmp_path: Path) -> None:
    pts = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.5], [3.0, 1.0]]
    csv_file = tmp_path / "p.csv"
    csv_file.write_text("x,y\n" + "\n".join(f"{x},{y}" for x, y in pts))
    json_file = tmp_path / "p.json"
    json_file.write_text(json.dumps({"points": pts}))
    a = make_pattern(csv_file, 4)
    b = make_pattern(json_file, 4)
    np.testing.assert_allclose(a, b)
    # exactly n points are used as given (centred), keeping the file's scale
    np.testing.assert_allclose(a, np.array(pts) - np.mean(pts, axis=0))
    # any other n resamples the polyline by arc length
    assert make_pattern(json_file, 7).shape == (7, 2)


@pytest.mark.parametrize(
    ("content", "suffix", "message"),
    [
        ("not json", ".json", "not valid JSON"),
        ('{"points": [[0, 0]]}', ".json", "at least 2 points"),
        ('[[0, 0], [1, "a"]]', ".json", "pairs of numbers"),
        ("[[0, 0], [NaN, 1]]", ".json", "finite"),
        ("0,0\n0.05,0\n", ".csv", "closer than 2R"),
        ("0,0\nfoo,bar\n1,1\n", ".csv", "line 2"),
        ('{"points": [[0, 0, 0], [1, 1, 1]]}', ".json", "pairs of numbers"),
    ],
)
def test_bad_pattern_files_are_refused(
    tmp_path: Path, content: str, suffix: str, message: str
) -> None:
    f = tmp_path / f"bad{suffix}"
    f.write_text(content)
    with pytest.raises(PatternError, match=message) as info:
        make_pattern(f, 2)
    assert "\n" not in str(info.value)


def test_unknown_name_and_too_few_robots() -> None:
    with pytest.raises(PatternError, match="unknown pattern"):
        make_pattern("hexagram", 10)
    with pytest.raises(PatternError, match="at least 2 robots"):
        make_pattern("circle", 1)


def test_dense_file_pattern_too_tight_for_many_robots(tmp_path: Path) -> None:
    f = tmp_path / "short.csv"
    f.write_text("0,0\n1,0\n")
    make_pattern(f, 5)  # 0.25 m apart: fine
    with pytest.raises(PatternError, match="closer than 2R"):
        make_pattern(f, 11)  # 0.1 m apart


def test_random_patterns_are_valid_and_seeded() -> None:
    from runtime.decision.patterns import random_pattern

    a = [random_pattern(np.random.default_rng(7), n) for n in range(2, 40, 3)]
    b = [random_pattern(np.random.default_rng(7), n) for n in range(2, 40, 3)]
    for p, q, n in zip(a, b, range(2, 40, 3), strict=True):
        np.testing.assert_array_equal(p, q)
        assert p.shape == (n, 2)
        assert min_spacing(p) == pytest.approx(DEFAULT_WORLD.pattern_spacing_m)
        assert np.ptp(p, axis=0).max() <= 1.1 * (n - 1) * DEFAULT_WORLD.pattern_spacing_m + 1e-9


def test_a_pattern_file_with_an_absurd_coordinate_is_refused_with_one_line(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from runtime.decision.patterns import MAX_PATTERN_COORD_M

    f = tmp_path / "far.csv"
    f.write_text("0,0\n1e300,0\n0,1\n")
    with pytest.raises(PatternError, match="at most") as e:
        make_pattern(str(f), 10)
    assert "\n" not in str(e.value) and f"{MAX_PATTERN_COORD_M:g}" in str(e.value)


def test_min_spacing_sweeps_like_the_distance_matrix_in_linear_memory() -> None:
    rng = np.random.default_rng(7)
    for n in (2, 3, 17, 300):
        for _ in range(20):
            p = rng.uniform(-5, 5, (n, 2))
            if n > 3:
                p[rng.integers(n)] = p[0]  # a duplicate: distance 0
            d = np.linalg.norm(p[:, None] - p[None], axis=-1)
            d[np.diag_indices(n)] = np.inf
            assert min_spacing(p) == pytest.approx(d.min(), abs=1e-12)
    line = np.stack([np.zeros(65_536), np.arange(65_536) * 0.5], axis=1)  # 64 GiB as a matrix
    assert min_spacing(line) == pytest.approx(0.5)
    assert np.isnan(min_spacing(np.array([[0.0, 0.0], [np.nan, 1.0]])))
