#!/usr/bin/env bash
# One-step set-up on a fresh Debian 12 machine: install what is missing, build, then
#   bash tools/bootstrap.sh demo   run the main job on the bundled data
#   bash tools/bootstrap.sh test   run the whole test suite in Release, the unit and cli
#                                  tiers again under the address + undefined-behaviour
#                                  sanitizers, then fuzz the input stages (tests/README.md)
# Run as root, or as a user with sudo. Safe to re-run: installs and builds are incremental.
set -euo pipefail

mode="${1:-}"
case "$mode" in
  demo|test) ;;
  *) echo "usage: bash tools/bootstrap.sh demo|test" >&2; exit 2 ;;
esac

cd "$(dirname "$0")/.."
jobs="$(nproc 2>/dev/null || echo 2)"

# python3-numpy, -scipy, -astropy and -pytest: the tests add lab defects to simulated frames
# and simulate spots by photon shooting with separate scripts (tests/support/lab_defects.py,
# reference_sensor.py) that share no code with the tool, and check those scripts themselves.
# python3-emcee and -matplotlib: the Python package's tests check its chain reader against
# emcee's own backend (python/tests/test_fit_reader.py) and run the documented example,
# which plots (docs/examples/load_fit.py).
# fitsverify (HEASARC's FITS validator): the tests check that every table and image the tool
# writes is valid FITS, without warnings, for astropy, TOPCAT and DS9.
# libopenmpi-dev and openmpi-bin: `mpirun -np N ccdpsf grid ...` shards a campaign across
# processes and machines (src/process_group.cc).
packages=(build-essential cmake pkg-config libceres-dev libeigen3-dev libgoogle-glog-dev
          libgflags-dev libcfitsio-dev libgtest-dev nlohmann-json3-dev libbenchmark-dev
          gnuplot-nox fitsverify python3-numpy python3-scipy python3-astropy
          python3-pytest python3-emcee python3-matplotlib libopenmpi-dev openmpi-bin)
# clang-14 and its sanitizer and libFuzzer runtimes: the test mode's sanitizer build, which
# also makes the fuzzers.
if [ "$mode" = test ]; then packages+=(clang-14 libclang-rt-14-dev); fi
missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ "${#missing[@]}" -gt 0 ]; then
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
  echo "== installing: ${missing[*]}"
  $sudo apt-get update -q
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

echo "== building (Release) in build/"
# The test run leaves the benchmarks out: nothing in the tests runs them, and their 18
# objects are ~1 of CI's 30 minutes on two cores. The demo's build (the default) has them.
benchmarks=ON
if [ "$mode" = test ]; then benchmarks=OFF; fi
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DCCDPSF_BUILD_BENCHMARKS="$benchmarks" > /dev/null
cmake --build build -j"$jobs"

if [ "$mode" = demo ]; then
  rm -rf out/campaign
  echo "== the main job: characterise the CCD PSF from the bundled lab campaign"
  echo "   (testdata/campaign_small: 7 settings at 600-890 nm and 23-158 ke-, each at one focus"
  echo "   and through focus, 56 exposures; joint fit with MCMC of every setting, then the"
  echo "   relations with wavelength and intensity and the Euclid VIS requirement checks)"
  ./build/ccdpsf trend --out=out/campaign testdata/campaign_small
  echo "== done: the report is $(pwd)/out/campaign/report.md (trend.json, CSV tables and"
  echo "   plots beside it; each setting's fit report under out/campaign/groups/; the"
  echo "   campaign's truth is testdata/campaign_small/truth.json)"
  exit 0
fi

# The test tiers (tests/README.md): unit and cli run in both builds below, e2e and the Python
# side in Release only. ctest starts the costliest cases first when it knows their costs, so
# the committed costs of the last measured run (tests/costs.txt) seed a fresh build's.
seed_costs() {
  mkdir -p "$1/Testing/Temporary"
  if [ ! -s "$1/Testing/Temporary/CTestCostData.txt" ]; then
    cp tests/costs.txt "$1/Testing/Temporary/CTestCostData.txt"
  fi
}
echo "== tests (Release): unit, cli, e2e and python tiers"
seed_costs build
(cd build && ctest --output-on-failure -j"$jobs")
/usr/bin/python3 tools/test_costs.py build --slowest 10

# One clang build serves the sanitizer tests and the fuzzers: AddressSanitizer and
# UndefinedBehaviorSanitizer everywhere, plus libFuzzer's coverage instrumentation (unused by
# the tests). -O1 with line tables only: a quicker build than -O2 -g, stacks still named.
echo "== building with clang: address + undefined sanitizers, libFuzzer harnesses (build-sanitize/)"
CC=clang-14 CXX=clang++-14 cmake -S . -B build-sanitize -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only -DNDEBUG" \
  -DCCDPSF_FUZZ=ON -DCCDPSF_E2E_TESTS=OFF -DCCDPSF_BUILD_BENCHMARKS=OFF > /dev/null
cmake --build build-sanitize -j"$jobs"
echo "== tests (sanitizers): unit and cli tiers"
seed_costs build-sanitize
(cd build-sanitize && ctest --output-on-failure -j"$jobs")
/usr/bin/python3 tools/test_costs.py build-sanitize --slowest 10

# Short fuzzing runs of the input stages from the committed seeds (README, "Fuzzing"): a
# regression in a reader shows up here within seconds. New inputs go to a scratch corpus,
# removed afterwards; a fixed seed makes the mutations repeatable. A failing input is kept
# as build-sanitize/crash-* (or leak-, timeout-, oom-).
scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
fuzz() {  # harness, corpus, dictionary, seconds
  echo "== fuzzing with $1 for $4 s"
  mkdir -p "$scratch/$1"
  if ! ./build-sanitize/"$1" "$scratch/$1" "$2" -dict="$3" -seed=1 -max_total_time="$4" \
       -timeout=30 -rss_limit_mb=2048 -artifact_prefix=build-sanitize/ -print_final_stats=1 \
       > "build-sanitize/$1.log" 2>&1; then
    tail -n 60 "build-sanitize/$1.log"
    echo "== $1 failed on the input in build-sanitize/ (crash-*, leak-*, timeout-* or oom-*);"
    echo "   README, \"Fuzzing\", says how to reproduce it and make it a regression test"
    exit 1
  fi
  grep -E "^#[0-9]+ +DONE|^stat::number_of_executed_units|^stat::peak_rss_mb" "build-sanitize/$1.log"
}
fuzz fits_input_fuzzer fuzz/corpus fuzz/fits.dict 30
fuzz text_input_fuzzer fuzz/text_corpus fuzz/text.dict 30
