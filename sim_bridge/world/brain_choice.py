"""Which brain runs each pattern: ``--brains`` of ``patternrl sim`` and ``patternrl launch``.

A choice is a :class:`BrainChoice` per pattern. ``none`` leaves the robots' brains
alone; ``rule:assign`` or one brain file (``.onnx``, e.g. ``exports/general.onnx``)
runs that brain for every pattern; a directory of brains (``<stem>.onnx`` +
``<stem>.json`` manifests) gives a brain per pattern, chosen by the manifest's
``pattern``, ``observation`` and ``n_robots`` (:func:`choose_brains`). The
launcher's ``auto`` (:func:`pick_brains`) prefers the shipped general brain, then
a directory with a brain for every pattern, then the rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from runtime.brain.brain import RULE_ASSIGN, RULES, BrainError, BrainManifest, sidecar_path
from runtime.decision.patterns import pattern_label
from runtime.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
GENERAL_BRAIN = "general.onnx"
"""The shipped general brain's file name in a brains directory: the default brain."""


@dataclass(frozen=True)
class BrainChoice:
    """The brain the world wants running for one pattern."""

    ref: str
    """``rule:assign`` or the path of an ``.onnx`` file."""
    brain_id: str
    kind: str
    """``rule``, ``general`` or ``paper``."""
    label: str
    """What tables print: the file name (or rule) and a short id."""


def rule_choice(ref: str = RULE_ASSIGN) -> BrainChoice:
    return BrainChoice(ref, ref, "rule", ref)


def scan_brains(directory: Path) -> list[tuple[Path, BrainManifest]]:
    """Every brain in ``directory``: (onnx path, manifest) for each readable sidecar."""
    out: list[tuple[Path, BrainManifest]] = []
    for side in sorted(directory.glob("*.json")):
        onnx = side.with_suffix(".onnx")
        if not onnx.is_file() or sidecar_path(onnx) != side:
            continue
        try:
            manifest = BrainManifest.from_json(side.read_text(encoding="utf-8"))
        except (BrainError, OSError, UnicodeDecodeError):
            continue
        out.append((onnx, manifest))
    return out


def choose_brains(
    directory: Path, patterns: list[str], n_robots: int, prefer: str = "general"
) -> tuple[dict[str, BrainChoice], list[str]]:
    """The brain for each pattern from a brains directory, and the patterns with none.

    A brain fits a pattern when its manifest names that pattern (by label), or
    names none and is of the general kind (:func:`brain_kind`); a paper brain must also
    observe ``n_robots``. Preference: the ``prefer`` kind, then a brain made for
    the pattern over a pattern-free one, then the file name.
    """
    found = scan_brains(directory)
    chosen: dict[str, BrainChoice] = {}
    missing: list[str] = []
    for p in patterns:
        label = pattern_label(p)
        fits = []
        for onnx, m in found:
            kind = brain_kind(m.observation.name)
            if m.pattern is not None and pattern_label(m.pattern) != label:
                continue
            if m.pattern is None and kind != "general":
                continue
            if not m.observation.accepts_team(n_robots):
                continue
            fits.append((kind != prefer, m.pattern is None, onnx.name, onnx, m))
        if not fits:
            missing.append(p)
            continue
        *_, onnx, m = min(fits, key=lambda f: f[:3])
        bid = m.brain_id
        chosen[p] = BrainChoice(str(onnx), bid, brain_kind(m.observation.name),
                                f"{onnx.name} ({bid[:8]})")
    return chosen, missing


def brain_kind(observation: str) -> str:
    """``paper`` for the paper's observation, else ``general`` (general and plan brains: any
    pattern, any team size)."""
    return "paper" if observation == "paper" else "general"


def file_choice(path: str | Path, n_robots: int) -> BrainChoice:
    """One brain file (``.onnx``, manifest beside it or inside) as a choice for any pattern.

    Raises :class:`InputError` when the file or its manifest cannot be read, or when
    its observation cannot drive ``n_robots`` (a paper brain made for another n).
    """
    from runtime.brain.swap import read_brain  # loads onnxruntime: only when a file is named

    try:
        manifest_json, _, brain_id = read_brain(str(path))
        m = BrainManifest.from_json(manifest_json)
    except BrainError as e:
        raise InputError(f"--brains {path}: {e}") from None
    if not m.observation.accepts_team(n_robots):
        raise InputError(f"--brains {path}: the brain reads the '{m.observation.name}' "
                         f"observation of {m.observation.n_robots} robots, not {n_robots}")
    name = Path(path).name
    return BrainChoice(str(path), brain_id, m.observation.name, f"{name} ({brain_id[:8]})")


def brains_from_arg(value: str, patterns: list[str], n: int, prefer: str
                    ) -> dict[str, BrainChoice] | None:
    """``none`` -> None; ``rule:...`` -> that rule for every pattern; a brain file (``.onnx``)
    -> that brain for every pattern; a directory -> scan it."""
    if value == "none":
        return None
    if value.startswith("rule:"):
        if value not in RULES:
            raise InputError(f"unknown rule brain '{value}' (known: {', '.join(RULES)})")
        return {p: rule_choice(value) for p in patterns}
    d = Path(value)
    if d.is_file():
        choice = file_choice(d, n)
        return {p: choice for p in patterns}
    if not d.is_dir():
        raise InputError(f"--brains {value}: not a directory, a brain file, 'rule:assign' "
                         "or 'none'")
    chosen, missing = choose_brains(d, patterns, n, prefer)
    if missing:
        raise InputError(f"--brains {value} has no brain for {', '.join(missing)} with {n} robots")
    return chosen


def brain_dirs() -> tuple[Path, ...]:
    """Where ``--brains auto`` looks: ``exports/`` here, then the project's."""
    return (Path("exports"), ROOT / "exports")


def pick_brains(value: str, patterns: list[str], n: int, prefer: str,
                search: tuple[Path, ...] | None = None
                ) -> tuple[dict[str, BrainChoice], str]:
    """(brain per pattern, a line saying where they came from).

    ``auto``: the general brain (``<dir>/general.onnx``) for every pattern when one
    of ``search`` (default :func:`brain_dirs`) has it and ``prefer`` is ``general``;
    else the first of them with a brain for every pattern; else ``rule:assign``.
    """
    if value != "auto":
        chosen = brains_from_arg(value, patterns, n, prefer)
        assert chosen is not None  # "none" is not offered by the launcher
        return chosen, f"brains: {value}"
    dirs = brain_dirs() if search is None else search
    note = ""
    if prefer == "general":
        for d in dirs:
            g = d / GENERAL_BRAIN
            if not g.is_file():
                continue
            try:
                choice = file_choice(g, n)
            except InputError as e:
                note = f"; {e}"
                break
            return ({p: choice for p in patterns},
                    f"brains: {choice.label} from {d}, the general brain, for every pattern")
    for d in dirs:
        if d.is_dir():
            chosen, missing = choose_brains(d, patterns, n, prefer)
            if not missing:
                return chosen, f"brains: {d} (a brain for every pattern){note}"
            if chosen:
                return ({p: rule_choice() for p in patterns},
                        f"brains: {RULE_ASSIGN} ({d} has none for {', '.join(missing)}){note}")
    return ({p: rule_choice() for p in patterns},
            f"brains: {RULE_ASSIGN} (no trained brains found){note}")
