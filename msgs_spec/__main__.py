"""python -m msgs_spec [--check | --write]: print the generated spec, or check/refresh msgs_spec/README.md."""

from __future__ import annotations

import argparse
import sys

from .spec_doc import README_PATH, readme_generated_block, render_spec, write_readme


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m msgs_spec", description=__doc__)
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--check", action="store_true", help="exit 1 if README.md's generated block is stale")
    g.add_argument("--write", action="store_true", help="rewrite README.md's generated block")
    args = ap.parse_args(argv)
    if args.write:
        changed = write_readme()
        print(f"{README_PATH}: {'updated' if changed else 'already up to date'}")
        return 0
    if args.check:
        ok = readme_generated_block(README_PATH.read_text(encoding="utf-8")) == render_spec()
        print(f"{README_PATH}: {'up to date' if ok else 'STALE: run python -m msgs_spec --write'}")
        return 0 if ok else 1
    sys.stdout.write(render_spec())
    return 0


if __name__ == "__main__":
    sys.exit(main())
