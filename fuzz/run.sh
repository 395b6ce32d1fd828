#!/usr/bin/env bash
# Coverage-guided fuzzing (cargo fuzz, libFuzzer) of marionette's readers, wire and the
# studio's requests.
#   fuzz/run.sh [SECONDS] [TARGET...]     default: 600 s for each of the eight targets, as many
#                                         at once as there are cores (FUZZ_JOBS)
# Seeds come from the bundled data (data/cmu, firmware-profile, a clip's targets, the real
# traffic of each bus transaction, the studio's requests and a page's messages); libFuzzer keeps what it finds in fuzz/corpus/TARGET and a
# crashing input in fuzz/artifacts/TARGET. Prints one line per target: executions, corpus size,
# crashes. Needs the nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-600}
shift || true
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    targets=(asf amc bvh profile targets wire_host wire_device studio)
fi

seeds=fuzz/seeds
rm -rf "$seeds"
mkdir -p "$seeds"/{asf,amc,bvh,profile,targets,studio}
cp data/cmu/*.asf "$seeds/asf/"
# AMC and BVH: the header and the first frames of each bundled clip (short inputs fuzz faster).
for f in data/cmu/*.amc; do
    awk '/^[0-9]+\r?$/ { n++ } n > 6 { exit } { print }' "$f" >"$seeds/amc/$(basename "$f")"
done
for f in data/cmu/*.bvh; do
    awk '/^Frames:/ { print "Frames: 4"; next } /^Frame Time/ { print; body = 1; next }
         body { if (++n > 4) exit } { print }' "$f" >"$seeds/bvh/$(basename "$f")"
done
cp firmware-profile/*.toml "$seeds/profile/"
# The studio: an API request of each kind, and a page's session (one message a line).
echo '{"effector": "lradius", "position": [5, 15, 5]}' >"$seeds/studio/target.json"
echo '{"effector": "rtibia", "position": null}' >"$seeds/studio/release.json"
echo '{"method": "dls", "compare": "ccd"}' >"$seeds/studio/solver.json"
cat >"$seeds/studio/session.jsonl" <<'PAGE'
{"type": "select", "effector": "lradius"}
{"type": "drag", "effector": "lradius", "position": [4.5, 16.0, 3.0], "t": 1764190000000.5}
{"type": "drag", "effector": "ltibia", "position": [-2.0, -14.0, 1.0]}
{"type": "solver", "method": "cg", "compare": "jt"}
{"type": "swivel", "deg": 35}
{"type": "pin", "effector": "rradius"}
{"type": "timeline", "playing": true, "looping": false, "speed": 1.5, "time": 0.25}
{"type": "release", "effector": "lradius"}
{"type": "reset"}
PAGE
# The seed tools are built with FUZZ_SEED_BUILD's cargo options when set (CI passes its test
# build's, so that the two builds share their artifacts).
read -r -a build <<<"${FUZZ_SEED_BUILD:-}"
cargo build -q "${build[@]}" --bin marionette --example wire_seeds
debug=${CARGO_TARGET_DIR:-target}/debug
for format in csv jsonl; do
    "$debug/marionette" targets data/cmu/16.asf data/cmu/16_15.amc --format "$format" --output "$seeds/targets/all.$format" >/dev/null
    head -n 40 "$seeds/targets/all.$format" >"$seeds/targets/16_15.$format"
    rm "$seeds/targets/all.$format"
done
"$debug/examples/wire_seeds" "$seeds"

cd fuzz
cargo +nightly fuzz build -O
# Each libFuzzer run is one single-threaded process: as many run at once as there are cores
# (FUZZ_JOBS to choose), each for the same fixed time.
parallel=${FUZZ_JOBS:-$(nproc)}
logs=$(mktemp -d)
trap 'rm -rf "$logs"' EXIT
fuzz_one() {
    local t=$1
    mkdir -p "corpus/$t"
    if cargo +nightly fuzz run -O "$t" "corpus/$t" "seeds/$t" -- \
        -max_total_time="$seconds" -seed=1 -timeout=10 -max_len=16384 -rss_limit_mb=4096 \
        -print_final_stats=1 >"$logs/$t.log" 2>&1; then
        echo 0 >"$logs/$t.crashes"
    else
        echo 1 >"$logs/$t.crashes"
    fi
}
for t in "${targets[@]}"; do
    while (($(jobs -rp | wc -l) >= parallel)); do
        wait -n || true
    done
    fuzz_one "$t" &
done
wait
status=0
for t in "${targets[@]}"; do
    crashes=$(cat "$logs/$t.crashes")
    if [ "$crashes" != 0 ]; then
        status=1
        tail -n 40 "$logs/$t.log"
    fi
    runs=$(awk '/stat::number_of_executed_units:/ { print $2 }' "$logs/$t.log")
    corpus=$(find "corpus/$t" -type f | wc -l)
    printf 'fuzz %-12s %6s s  %12s executions  corpus %6s  crashes %s\n' "$t" "$seconds" "${runs:-?}" "$corpus" "$crashes"
done
exit $status
