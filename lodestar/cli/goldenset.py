"""``lodestar goldenset``: write a named golden image set (frames, truth, expected
detection)."""
from lodestar.sim import goldenset
from lodestar.sim.goldenset import SETS


def add_parser(sub):

    p = sub.add_parser("goldenset", help="write a named golden image set",
                       description="Write frames (16-bit PNG), truth and expected detection.")
    p.add_argument("name", choices=sorted(SETS))
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=run)


def run(args):

    names = goldenset.generate(args.name, args.out, progress=lambda n: print("wrote", n))
    print(f"{len(names)} frames in {args.out}")
    return 0
