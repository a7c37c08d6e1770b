"""``patternrl``: the one command line of the project.

Each sub-command lives in the package that owns it and exposes
``add_arguments(parser)`` and ``run(args) -> int``. Modules are imported only
for the command that runs, so ``patternrl robot`` never loads torch or pymunk.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import os
import sys
import tomllib
from pathlib import Path

DIST_NAME = "pattern-rl"

# command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "patterns": (
        "sim_bridge.launch.cli_patterns",
        "list built-in patterns, or draw one to check it",
    ),
    "robot": ("runtime.robot.process", "run one robot: observe peers over Zenoh, act with a brain"),
    "swap": ("runtime.brain.swap", "hot-swap the brain of running robots"),
    "train": ("trainer.cli", "train a brain with Pattern-RL (or standard PPO) and export ONNX"),
    "eval": ("trainer.evaluate", "measure a brain: success, collisions, steps and travel ratios"),
    "sim": ("sim_bridge.world.sim", "play the pymunk world over Zenoh, recording an MCAP log"),
    "launch": (
        "sim_bridge.launch.launch",
        "start a world and one robot process per robot: the demo",
    ),
    "replay": ("sim_bridge.log.replay", "report, draw, play back or re-run an MCAP log"),
    "keys": (
        "sim_bridge.launch.swarm_keys",
        "create a swarm's certificate authority and identities",
    ),
    "brain": ("runtime.brain.cli", "make a signing key, sign a brain, verify its signature"),
    "router": ("sim_bridge.launch.router", "run the swarm's Zenoh router: every member its client"),
    "record": (
        "sim_bridge.log.record",
        "record a running swarm (simulated or real) into an MCAP log",
    ),
    "coordinate": (
        "sim_bridge.launch.coordinator",
        "a real swarm's coordinator: publish the patterns, judge formed, record",
    ),
}


def version() -> str:
    """The installed package's version; from ``pyproject.toml`` when run from a source tree."""
    try:
        return importlib.metadata.version(DIST_NAME)
    except importlib.metadata.PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
    try:
        project = tomllib.loads(pyproject.read_text())["project"]
    except (OSError, tomllib.TOMLDecodeError, KeyError):
        return "unknown"
    return str(project.get("version", "unknown")) if project.get("name") == DIST_NAME else "unknown"


def _top_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="patternrl",
        description="Pattern-RL: learned multi-robot pattern formation.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="commands:\n"
        + "\n".join(f"  {name:<10} {doc}" for name, (_, doc) in COMMANDS.items())
        + "\n\nRun 'patternrl COMMAND --help' for a command's options.",
    )
    p.add_argument("command", choices=list(COMMANDS), metavar="COMMAND", help="what to run")
    p.add_argument("-V", "--version", action="version", version=f"patternrl {version()}")
    return p


EXIT_CLOSED_STDOUT = 141
"""The exit code when the reader of stdout went away (``patternrl ... | head -1``): 128 +
SIGPIPE, what a shell reports for a tool that a closed pipe ended."""


def main(argv: list[str] | None = None) -> int:
    try:
        code = _main(argv)
        sys.stdout.flush()  # a closed stdout shows here, not in the interpreter's exit
        return code
    except KeyboardInterrupt:  # Ctrl-C while starting up (imports, options): one line
        print("patternrl: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader closed stdout: stop quietly, nothing to tell it
        _silence_stdout()
        return EXIT_CLOSED_STDOUT


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's last flush does not fail too."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # no real stdout (a test's capture): nothing to flush
        pass


def _main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-V", "--version"):
        print(f"patternrl {version()}")
        return 0
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        parser = _top_parser()
        if not argv:
            parser.print_help()
            return 2
        parser.parse_args(argv[:1])  # prints help or a one-line error, exits
        return 0
    name = argv[0]
    module_name, doc = COMMANDS[name]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"patternrl {name}", description=doc)
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    try:
        return int(module.run(args))
    except KeyboardInterrupt:
        print(f"patternrl {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
