#!/usr/bin/env bash
# Builds the fuzz targets (cargo fuzz, no sanitizer, so a stable toolchain does) and runs
# each for SECONDS (default 30), seeded from the bundled scenes and a checkpoint that a
# tiny render writes. A crash fails the run; its input is left in
# fuzz/artifacts/<target>/: copy it to fuzz/regressions/<target>/ with the fix, where
# the workspace's tests run it on every test run.
#   fuzz/run.sh [SECONDS]        needs cargo-fuzz (cargo install cargo-fuzz --locked) and
#                                a release build of the coordinator (target/release)
set -euo pipefail
cd "$(dirname "$0")"
secs=${1:-30}
targets=(scene_toml obj mtl checkpoint wire)
corpus=$(mktemp -d)
trap 'rm -rf "$corpus"' EXIT
for t in "${targets[@]}"; do mkdir -p "$corpus/$t"; done
seed() { cp "$2" "$corpus/$1/$(sha256sum < "$2" | cut -c1-16)"; }
while IFS= read -r -d '' f; do seed scene_toml "$f"; done < <(find ../scenes -name '*.toml' -print0)
while IFS= read -r -d '' f; do seed obj "$f"; done < <(find ../scenes -name '*.obj' -size -256k -print0)
while IFS= read -r -d '' f; do seed mtl "$f"; done < <(find ../scenes -name '*.mtl' -print0)
ck="$corpus/ck"
../target/release/coordinator render ../scenes/cornell-box/scene.toml --width 16 --height 16 --spp 8 \
    --tile 8 --batch-spp 4 --local-workers 0 --checkpoint "$ck" -q -o "$corpus/ck.exr" > /dev/null
seed checkpoint "$ck/checkpoint.tfck"
for t in "${targets[@]}"; do
    if [ -d "regressions/$t" ]; then cp regressions/"$t"/* "$corpus/$t/" 2>/dev/null || true; fi
done
cargo fuzz build -s none --dev
for t in "${targets[@]}"; do
    echo "fuzz: $t for ${secs}s ($(ls "$corpus/$t" | wc -l) seeds)"
    # -rss_limit_mb: a parser that allocates without bound is a crash, not a slow run.
    log="$corpus/$t.log"
    if ! cargo fuzz run -s none --dev "$t" "$corpus/$t" -- -max_total_time="$secs" -rss_limit_mb=2048 -timeout=10 \
        -print_final_stats=1 > "$log" 2>&1; then
        grep -E "ERROR|SUMMARY|panicked|Test unit written|Base64" "$log" | head -20
        echo "fuzz: $t found a crash (its input is in fuzz/artifacts/$t/)"
        exit 1
    fi
    grep -E "^stat::(number_of_executed_units|peak_rss_mb)" "$log" | tr -s ' ' | sed 's/^/    /'
done
