"""``python -m bench.fitgen N --seed S -o DIR``: generate a set of unseen fits into DIR."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    """Generate the set; print one line per pair. Returns the exit status."""
    from bench.fitgen import KernelMissing, generate
    from bench.fitgen.scenes import SceneNewFailed

    parser = argparse.ArgumentParser(prog="python -m bench.fitgen",
                                     description="Generate N unseen fits, each a scene made "
                                     "by `skelasm scene new`, with its ground truth (fit.json).")
    parser.add_argument("count", type=int, help="pairs to generate")
    parser.add_argument("--seed", type=int, required=True, help="the seed that draws the set")
    parser.add_argument("-o", "--output", required=True, help="folder (new or empty)")
    args = parser.parse_args(argv)
    try:
        pairs = generate(args.count, args.seed, args.output)
    except (KernelMissing, FileExistsError, SceneNewFailed) as exc:
        print(f"python -m bench.fitgen: {exc}", file=sys.stderr)
        return 2
    for p in pairs:
        t = p.truth
        print(f"{p.folder.name}: {t.description}; {t.formats[0]} + {t.formats[1]}, {t.unit}; "
              f"free {t.free_names}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
