"""``patternrl``: the one command line of the project.

Each sub-command lives in the package that owns it and exposes
``add_arguments(parser)`` and ``run(args) -> int``. Modules are imported only
for the command that runs, so ``patternrl robot`` never loads torch or pymunk.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# command -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "patterns": ("sim_bridge.cli_patterns", "list built-in patterns, or draw one to check it"),
    "robot": ("runtime.robot", "run one robot: observe peers over Zenoh, act with a brain"),
    "swap": ("runtime.swap", "hot-swap the brain of running robots"),
    "train": ("trainer.cli", "train a brain with Pattern-RL (or standard PPO) and export ONNX"),
    "eval": ("trainer.evaluate", "measure a brain: success, collisions, steps and travel ratios"),
    "sim": ("sim_bridge.sim", "play the pymunk world over Zenoh, recording an MCAP log"),
    "launch": ("sim_bridge.launch", "start a world and one robot process per robot: the demo"),
    "replay": ("sim_bridge.replay", "report, draw, play back or re-run an MCAP log"),
    "record": ("sim_bridge.record", "record a running swarm (simulated or real) into an MCAP log"),
}


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
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
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
