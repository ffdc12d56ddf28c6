#!/usr/bin/env python3
"""What each test case cost in a build's last ctest run, from ctest's own record.

    /usr/bin/python3 tools/test_costs.py BUILD [--slowest N] [--update tests/costs.txt]

ctest keeps, per case, the number of runs and the mean wall time [s] in
BUILD/Testing/Temporary/CTestCostData.txt ("name runs seconds" lines, then "---" and the
failed cases) and starts the costliest cases first when it has them. --slowest prints the N
costliest cases with the tier total; --update rewrites the committed costs (the file
tools/bootstrap.sh copies into a fresh build, so that CI's first run schedules well) with
this build's cases, keeping the lines of cases this build did not run (e.g. the e2e tier
when BUILD is the sanitizer build). Standard library only.
"""
import argparse
import os
import sys


def read_costs(path):
    """{name: (runs, seconds)} from a CTestCostData.txt-format file; {} if it is absent."""
    costs = {}
    if not os.path.isfile(path):
        return costs
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if line == "---":
                break
            parts = line.split()
            if len(parts) != 3:
                continue
            try:
                costs[parts[0]] = (int(parts[1]), float(parts[2]))
            except ValueError:
                continue
    return costs


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("build", help="a build folder where ctest has run")
    parser.add_argument("--slowest", type=int, default=0, metavar="N",
                        help="print the N costliest cases")
    parser.add_argument("--update", metavar="FILE", help="merge this build's costs into FILE")
    args = parser.parse_args()
    path = os.path.join(args.build, "Testing", "Temporary", "CTestCostData.txt")
    costs = read_costs(path)
    if not costs:
        print(f"test_costs.py: no ctest cost data in {path}", file=sys.stderr)
        return 1
    if args.slowest > 0:
        ranked = sorted(costs.items(), key=lambda kv: -kv[1][1])
        total = sum(seconds for _, seconds in costs.values())
        print(f"== the {min(args.slowest, len(ranked))} costliest of {len(ranked)} cases in "
              f"{args.build} (wall s each; {total:.0f} s in all)")
        for name, (_, seconds) in ranked[:args.slowest]:
            print(f"   {seconds:8.2f}  {name}")
    if args.update:
        merged = read_costs(args.update)
        for name, (_, seconds) in costs.items():
            merged[name] = (1, seconds)
        with open(args.update + ".tmp", "w", encoding="utf-8") as f:
            for name in sorted(merged):
                f.write(f"{name} 1 {merged[name][1]:.3f}\n")
            f.write("---\n")
        os.replace(args.update + ".tmp", args.update)
    return 0


if __name__ == "__main__":
    sys.exit(main())
