#!/bin/bash
# A farm's memory over many jobs: `coordinator serve` with one 2-thread worker, N ×
# `submit scenes/cornell-box/scene.toml --width 256 --spp 8 --wait`, VmRSS of serve a second
# after jobs 1, 10, 25, 50, 75, 100. Usage (after cargo build --release):
#   bench/farm_memory.sh N [serve options, e.g. --retain-finished-ms 0]
set -u
N=$1; shift
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BIN=$ROOT/target/release/coordinator
D=$(mktemp -d)
$BIN serve --listen 127.0.0.1:0 --store $D/store "$@" > $D/serve.out 2>$D/serve.err &
SP=$!
for i in $(seq 50); do grep -q listening $D/serve.out && break; sleep 0.1; done
URL=$(sed -n 's/listening on //p' $D/serve.out)
$BIN worker --coordinator $URL --threads 2 --cache $D/cache > /dev/null 2>&1 &
WP=$!
rss() { grep VmRSS /proc/$SP/status | awk '{print $2}'; }
echo "idle $(rss)"
for i in $(seq $N); do
  $BIN submit $ROOT/scenes/cornell-box/scene.toml --width 256 --spp 8 --wait -q -o $D/out.exr --coordinator $URL > /dev/null 2>&1 || echo "job $i failed"
  sleep 1
  case $i in 1|10|25|50|75|100) echo "$i $(rss)";; esac
done
kill $WP; kill $SP; wait 2>/dev/null
rm -rf $D
