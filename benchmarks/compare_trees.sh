#!/bin/bash
# Side-by-side speed of two checkouts, alternating them round by round (the machine's load moves
# both alike): `runner` prints bench_runner.py's median speed of seed 0 per tree and round; `study`
# prints the process CPU seconds of `rig study protocols/joint_estimation.yaml --seeds 0-23 --jobs 1`
# (object-level devices) per tree and round. Both trees run on this venv's interpreter.
#
#   benchmarks/compare_trees.sh runner|study BASE_TREE HEAD_TREE [ROUNDS]
set -euo pipefail
mode=$1; base=$2; head=$3; rounds=${4:-3}
python=$(dirname "$(readlink -f "$0")")/../.venv/bin/python
for i in $(seq "$rounds"); do
  for tree in "$base" "$head"; do
    case $mode in
      runner)
        speed=$(cd "$tree" && PYTHONPATH=$tree "$python" benchmarks/bench_runner.py --seeds 0 | grep "median speed")
        echo "$i $tree $speed" ;;
      study)
        /usr/bin/time -f "$i $tree cpu_s=%U+%S wall_s=%e" env PYTHONPATH="$tree" "$python" -m rig.cli study \
          "$tree/protocols/joint_estimation.yaml" --seeds 0-23 --jobs 1 --json > /dev/null ;;
      *) echo "mode: runner or study" >&2; exit 2 ;;
    esac
  done
done
