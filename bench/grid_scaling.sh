#!/usr/bin/env bash
# Timed runs of `ccdpsf grid` on a full-sensor spot grid made by the independent script
# tests/support/grid_frames.py: wall and CPU time, peak memory, per-spot cost, one process
# against two (threads and MPI ranks), and a check that every run writes the same psf_map.
#
#   bash bench/grid_scaling.sh [BUILD_DIR] [REPEATS] [EXTRA GRID OPTIONS...]
#   bash bench/grid_scaling.sh build 3                 # MCMC (target ESS 400), 3 repeats
#   bash bench/grid_scaling.sh build 3 --nomcmc        # MAP + Laplace only
#
# Frames: 3 exposures of 4096 x 4096, a 7 x 7 grid (GRID_SIZE / GRID_N / GRID_EXPOSURES
# override), written once into $TMPDIR/ccdpsf_grid_bench. Prints one line per run and the
# medians; the machine and its load (uptime) before and after.
set -euo pipefail
build="${1:-build}"
repeats="${2:-3}"
shift $(( $# > 2 ? 2 : $# ))
extra=("$@")
binary="$(cd "$build" && pwd)/ccdpsf"
here="$(cd "$(dirname "$0")/.." && pwd)"
size="${GRID_SIZE:-4096}"
n="${GRID_N:-7}"
exposures="${GRID_EXPOSURES:-3}"
work="${TMPDIR:-/tmp}/ccdpsf_grid_bench"
frames="$work/frames_${size}_${n}_${exposures}"
if [ ! -f "$frames/truth.json" ]; then
  rm -rf "$frames"
  /usr/bin/python3 "$here/tests/support/grid_frames.py" "$frames" --size "$size" --grid "$n" \
    --exposures "$exposures" > /dev/null
fi
files=("$frames"/frame_*.fits)
frame_mb=$(( $(stat -c %s "${files[0]}") / 1048576 ))
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')"
echo "load before: $(uptime | sed 's/.*load average: //')"
echo "frames: ${#files[@]} x ${size}^2 (${frame_mb} MiB each on disk), ${n}x${n} grid; options: ${extra[*]:-(defaults)}"

# One run: run NAME THREADS [LAUNCHER...]; prints "wall_s cpu_s peak_rss_mb spots" (the CPU of
# every process of an MPI job is counted, as mpirun's children's).
run() {
  local out="$work/out_$1" threads="$2"; shift 2
  rm -rf "$out"
  local log="$work/log"
  /usr/bin/time -f "%e %U %S %M" -o "$work/time" "$@" "$binary" grid --out="$out" \
    --threads="$threads" "${extra[@]}" "${files[@]}" > "$log" 2>&1 || { cat "$log" >&2; exit 1; }
  read -r wall user sys rss < "$work/time"
  local spots
  spots=$(grep -c '^\(\[process [0-9]*\] \)\?\[[0-9]*/[0-9]*\]' "$log" || true)
  echo "$wall $(echo "$user + $sys" | bc) $(( rss / 1024 )) $spots"
}

median() { sort -n | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }

declare -A wall cpu
# name:threads per process:launcher
for config in "1x1:1:" "1x2:2:" "mpi2x1:1:mpirun -np 2"; do
  IFS=: read -r name threads launcher <<< "$config"
  read -r -a command <<< "$launcher"
  walls=() cpus=()
  for r in $(seq 1 "$repeats"); do
    line=$(run "$name" "$threads" "${command[@]}")
    read -r w c m s <<< "$line"
    echo "$name run $r: wall ${w} s, CPU ${c} s, peak RSS ${m} MB (largest process), spot fits ${s}"
    walls+=("$w") cpus+=("$c")
  done
  wall[$name]=$(printf '%s\n' "${walls[@]}" | median)
  cpu[$name]=$(printf '%s\n' "${cpus[@]}" | median)
  cp "$work/out_$name/psf_map.fits" "$work/psf_map_$name.fits"
done
echo "load after: $(uptime | sed 's/.*load average: //')"
spots=$(grep -c ',ok,\|,suspect,' "$work/out_1x1/psf_map.csv" || true)
for name in 1x1 1x2 mpi2x1; do
  echo "median $name: wall ${wall[$name]} s, CPU ${cpu[$name]} s, per fitted spot $(echo "scale=2; ${cpu[$name]} / $spots" | bc) s CPU"
done
echo "speed-up over 1x1: 1x2 $(echo "scale=2; ${wall[1x1]} / ${wall[1x2]}" | bc)x, mpi2x1 $(echo "scale=2; ${wall[1x1]} / ${wall[mpi2x1]}" | bc)x"
same=yes
for name in 1x2 mpi2x1; do
  cmp -s "$work/psf_map_1x1.fits" "$work/psf_map_$name.fits" || same=no
done
echo "psf_map.fits identical across 1x1, 1x2 and mpi2x1: $same"
