"""Target patterns: built-in curves and user files, resampled to any team size.

A pattern is an array of shape (n, 2) in metres. Only its shape matters: the
team forms it up to translation (orientation and scale are fixed).

Built-ins are curves resampled by arc length to ``n`` points and scaled so the
closest two points are exactly ``world.pattern_spacing_m`` apart (4R by
default: parked robots keep a diameter of gap).

User patterns come from a file:

* CSV: one ``x,y`` pair per line (a header line and ``#`` comments are allowed);
* JSON: ``[[x, y], ...]`` or ``{"points": [[x, y], ...], "closed": false}``.

A file keeps its own scale (metres). If it holds exactly ``n`` points they are
the pattern as given; otherwise the points are read as a polyline (closed if
``"closed": true`` or if the first and last points coincide) and resampled by
arc length to ``n`` points. Any problem raises :class:`PatternError` with a
one-line message; the CLI turns it into exit code 2.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from runtime.errors import InputError
from runtime.world_config import DEFAULT_WORLD, MAX_PATTERN_COORD_M, WorldConfig

Points = NDArray[np.float64]


class PatternError(InputError):
    """A pattern that cannot be used; the message is one line."""


def _circle(m: int) -> Points:
    a = np.linspace(0.0, 2.0 * math.pi, m, endpoint=False)
    return np.stack([np.cos(a), np.sin(a)], axis=1)


def _heart(m: int) -> Points:
    # The classic heart curve x = 16 sin^3 s, y = 13 cos s - 5 cos 2s - 2 cos 3s - cos 4s.
    s = np.linspace(0.0, 2.0 * math.pi, m, endpoint=False)
    x = 16.0 * np.sin(s) ** 3
    y = 13.0 * np.cos(s) - 5.0 * np.cos(2 * s) - 2.0 * np.cos(3 * s) - np.cos(4 * s)
    return np.stack([x, y], axis=1) / 16.0


def _cross(m: int) -> Points:
    # A centre point and four arms on a unit lattice; arms differ by at most one point.
    arms = [(m - 1) // 4 + (1 if a < (m - 1) % 4 else 0) for a in range(4)]
    pts = [(0.0, 0.0)]
    for (dx, dy), length in zip(((1, 0), (0, 1), (-1, 0), (0, -1)), arms, strict=True):
        pts += [(dx * s, dy * s) for s in range(1, length + 1)]
    return np.asarray(pts, dtype=np.float64)


def _polyline(vertices: list[tuple[float, float]]) -> Callable[[int], Points]:
    v = np.asarray(vertices, dtype=np.float64)
    return lambda m: v


# name -> (dense curve generator, closed?, one-line description)
_BUILTINS: dict[str, tuple[Callable[[int], Points], bool, str]] = {
    "circle": (_circle, True, "regular n-gon"),
    "line": (_polyline([(-1.0, 0.0), (1.0, 0.0)]), False, "points evenly spaced on a line"),
    "cross": (_cross, False, "a plus sign: a centre point and four arms of (nearly) equal length"),
    "heart": (_heart, True, "the classic heart curve"),
    "triangle": (
        _polyline([(0.0, 1.0), (-math.sqrt(3) / 2, -0.5), (math.sqrt(3) / 2, -0.5), (0.0, 1.0)]),
        True,
        "an equilateral triangle outline",
    ),
}

BUILTIN_PATTERNS: tuple[str, ...] = tuple(_BUILTINS)


def describe_builtins() -> dict[str, str]:
    """Name -> one-line description of every built-in pattern."""
    return {name: spec[2] for name, spec in _BUILTINS.items()}


def resample_polyline(vertices: Points, n: int, closed: bool) -> Points:
    """``n`` points evenly spaced by arc length along a polyline.

    A closed polyline gets ``n`` points around its loop (no duplicate at the
    seam); an open one gets both end points.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if closed:
        if not np.allclose(v[0], v[-1]):
            v = np.vstack([v, v[:1]])
    seg = np.linalg.norm(np.diff(v, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-12])
    v = v[keep]
    seg = seg[seg > 1e-12]
    if len(v) < 2 or seg.sum() <= 0.0:
        raise PatternError("pattern polyline has zero length")
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    if n == 1:
        targets = np.array([0.0])
    elif closed:
        targets = np.linspace(0.0, total, n, endpoint=False)
    else:
        targets = np.linspace(0.0, total, n)
    x = np.interp(targets, s, v[:, 0])
    y = np.interp(targets, s, v[:, 1])
    return np.stack([x, y], axis=1)


def min_spacing(points: Points) -> float:
    """Smallest distance between two points of a pattern (inf for fewer than 2; nan if any is).

    Sort and sweep, O(n log n) time and O(n) memory on patterns (points >= 2R
    apart): sort along the wider axis, then compare each point with its k-th
    successor for k = 1, 2, ... while some pair k apart in that order is closer
    along the axis than the best distance found. A distance matrix would take
    O(n^2) memory (64 GiB for 65,536 points).
    """
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    if n < 2:
        return math.inf
    if not np.isfinite(p).all():
        return math.nan  # never "far enough apart": every caller compares with >=
    axis = int(np.argmax(np.ptp(p, axis=0)))
    p = p[np.argsort(p[:, axis], kind="stable")]
    key = p[:, axis]
    best = math.inf
    for k in range(1, n):
        gap = key[k:] - key[:-k]
        close = gap < best
        if not close.any():
            break
        d = p[k:][close] - p[:-k][close]
        best = min(best, float(np.sqrt(np.min(d[:, 0] ** 2 + d[:, 1] ** 2))))
    return best


def _builtin(name: str, n: int, world: WorldConfig) -> Points:
    gen, closed, _ = _BUILTINS[name]
    if name in ("circle", "cross"):
        dense = gen(n)  # exact: a regular n-gon, a lattice cross
    else:
        dense = resample_polyline(gen(2048) if name == "heart" else gen(0), n, closed)
    gap = min_spacing(dense)
    if not math.isfinite(gap):  # n == 1
        return np.zeros((1, 2))
    pts = dense * (world.pattern_spacing_m / gap)
    out: Points = pts - pts.mean(axis=0)
    return out


def _read_points_file(path: Path) -> tuple[Points, bool]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise PatternError(f"cannot read pattern file {path}: {e}") from None
    closed = False
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise PatternError(f"pattern file {path} is not valid JSON: {e}") from None
        if isinstance(data, dict):
            closed = bool(data.get("closed", False))
            data = data.get("points")
        rows = data
    else:
        rows = []
        for line_no, row in enumerate(csv.reader(text.splitlines()), start=1):
            if not row or row[0].strip().startswith("#"):
                continue
            try:
                rows.append([float(c) for c in row[:2]] if len(row) >= 2 else row)
            except ValueError:
                if line_no == 1:  # a header line
                    continue
                raise PatternError(
                    f"pattern file {path}, line {line_no}: expected two numbers 'x,y'"
                ) from None
    try:
        pts = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise PatternError(f"pattern file {path}: points must be pairs of numbers") from None
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise PatternError(f"pattern file {path}: points must be pairs of numbers [x, y]")
    if not np.isfinite(pts).all():
        raise PatternError(f"pattern file {path}: points must be finite numbers")
    if np.abs(pts).max(initial=0.0) > MAX_PATTERN_COORD_M:
        raise PatternError(
            f"pattern file {path}: a coordinate is {np.abs(pts).max():g} m, "
            f"at most {MAX_PATTERN_COORD_M:g} m"
        )
    if len(pts) < 2:
        raise PatternError(f"pattern file {path}: needs at least 2 points, has {len(pts)}")
    if np.allclose(pts[0], pts[-1]) and len(pts) > 2:
        closed = True
    return pts, closed


def make_pattern(name_or_path: str | Path, n: int, world: WorldConfig = DEFAULT_WORLD) -> Points:
    """The target pattern for ``n`` robots, centred on the origin, shape (n, 2), metres.

    ``name_or_path`` is a built-in name (see :data:`BUILTIN_PATTERNS`) or a
    path to a CSV/JSON file of points. Raises :class:`PatternError` for an
    unknown name, an unreadable or malformed file, non-finite values, fewer
    than 2 points, or points closer than 2R after resampling.
    """
    if n < 2:
        raise PatternError(f"a pattern needs at least 2 robots, got {n}")
    key = str(name_or_path)
    if key in _BUILTINS:
        pts = _builtin(key, n, world)
    else:
        path = Path(key)
        if not path.exists():
            known = ", ".join(BUILTIN_PATTERNS)
            raise PatternError(f"unknown pattern '{key}': not a built-in ({known}) nor a file")
        raw, closed = _read_points_file(path)
        if len(raw) == n and not (closed and np.allclose(raw[0], raw[-1])):
            pts = raw.copy()
        else:
            pts = resample_polyline(raw, n, closed)
        pts = pts - pts.mean(axis=0)
    gap = min_spacing(pts)
    if not gap >= world.min_separation_m:  # NaN too
        raise PatternError(
            f"pattern '{key}' for {n} robots puts two points {gap:.3f} m apart, "
            f"closer than 2R = {world.min_separation_m:.3f} m"
        )
    return pts


def pattern_label(name_or_path: str | Path) -> str:
    """A short name for logs and tables: the built-in name or the file's stem."""
    key = str(name_or_path)
    return key if key in _BUILTINS else Path(key).stem


def random_pattern(
    rng: np.random.Generator, n: int, world: WorldConfig = DEFAULT_WORLD
) -> Points:
    """A random shape for ``n`` robots, for training brains that form any pattern.

    Draws one of three families with equal odds, each scaled like the
    built-ins (closest pair exactly ``world.pattern_spacing_m`` apart) and
    centred:

    * a smooth closed curve ``r(theta) = 1 + sum_k a_k cos(k theta + phi_k)``, k = 2..4;
    * an open polyline through 2 to 5 random vertices;
    * a scattered point set (rejection-sampled with a minimum gap, then rescaled).
    """
    if n < 2:
        raise PatternError(f"a pattern needs at least 2 robots, got {n}")
    limit = 1.1 * (n - 1) * world.pattern_spacing_m  # no wider than a line of n
    for _ in range(20):
        pts = _random_shape(rng, n, world)
        if float(np.ptp(pts, axis=0).max()) <= limit:
            return pts
    return _builtin("circle", n, world)


def _random_shape(rng: np.random.Generator, n: int, world: WorldConfig) -> Points:
    family = int(rng.integers(3))
    if family == 0:
        theta = np.linspace(0.0, 2.0 * math.pi, 512, endpoint=False)
        r = np.ones_like(theta)
        for k in (2, 3, 4):
            r += rng.uniform(0.0, 0.3 / k) * np.cos(k * theta + rng.uniform(0, 2 * math.pi))
        dense = np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)
        pts = resample_polyline(dense, n, closed=True)
    elif family == 1:
        m = int(rng.integers(2, 6))
        verts = rng.uniform(-1.0, 1.0, (m, 2))
        pts = resample_polyline(verts, n, closed=False)
    else:
        side = math.sqrt(n) * 1.6
        chosen: list[NDArray[np.float64]] = []
        while len(chosen) < n:
            q = rng.uniform(0.0, side, 2)
            if all(float(np.hypot(*(q - c))) >= 1.0 for c in chosen):
                chosen.append(q)
            else:
                side *= 1.002  # bounded: the box grows until n points fit
        pts = np.asarray(chosen)
    gap = min_spacing(pts)
    if not math.isfinite(gap) or gap <= 1e-9:
        return _builtin("circle", n, world)
    pts = pts * (world.pattern_spacing_m / gap)
    out: Points = pts - pts.mean(axis=0)
    return out
