#!/bin/bash
# What security costs a render: one farm job (cornell-box 256², SPP spp, tiles 32, batches
# of 8) on `coordinator serve` with two 1-thread workers, timed from submit to image, in
# three configurations, interleaved for ROUNDS rounds (medians; this machine is shared):
#   plain    no TLS, --verify 0
#   tls      --tls (mTLS workers, a user token), --verify 0
#   verify   no TLS, --verify 0.02 (the default: 2% of units and each worker's first 4
#            results rendered twice)
# Usage (after cargo build --release): bench/security.sh [ROUNDS=3] [SPP=64]
set -eu
ROUNDS=${1:-3}
SPP=${2:-64}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BIN=$ROOT/target/release
D=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null; rm -rf "$D"' EXIT
$BIN/coordinator certs init "$D/tls" > /dev/null

one() { # mode → seconds
  local mode=$1 serve_args=(--listen 127.0.0.1:0 --store "$D/store-$1-$RANDOM" --verify 0) client=() worker=()
  case $mode in
    tls) serve_args+=(--tls "$D/tls"); client=(--tls "$D/tls"); worker=(--tls "$D/tls") ;;
    verify) serve_args=(--listen 127.0.0.1:0 --store "$D/store-$1-$RANDOM" --verify 0.02) ;;
  esac
  rm -f "$D/serve.out"
  $BIN/coordinator serve "${serve_args[@]}" > "$D/serve.out" 2> /dev/null &
  local sp=$!
  for _ in $(seq 100); do grep -q listening "$D/serve.out" 2> /dev/null && break; sleep 0.05; done
  local url
  url=$(sed -n 's/listening on //p' "$D/serve.out")
  $BIN/worker --coordinator "$url" --threads 1 --cache "$D/c1-$RANDOM" "${worker[@]}" > /dev/null 2>&1 &
  local w1=$!
  $BIN/worker --coordinator "$url" --threads 1 --cache "$D/c2-$RANDOM" "${worker[@]}" > /dev/null 2>&1 &
  local w2=$!
  local t0 t1
  t0=$(date +%s.%N)
  TILEFARM_TOKEN=$(cat "$D/tls/admin.token") $BIN/coordinator submit "$ROOT/scenes/cornell-box/scene.toml" \
    --width 256 --spp "$SPP" --tile 32 --batch-spp 8 --wait -q -o "$D/$mode.exr" --coordinator "$url" \
    "${client[@]}" > /dev/null
  t1=$(date +%s.%N)
  kill $w1 $w2 $sp; wait $w1 $w2 $sp 2> /dev/null || true
  echo "$t1 - $t0" | bc
}

declare -A times
one plain > /dev/null # warm-up: binaries and the scene in the page cache
for r in $(seq "$ROUNDS"); do
  for mode in plain tls verify; do
    s=$(one $mode)
    times[$mode]+="$s "
    echo "round $r $mode ${s}s"
  done
done
median() { tr ' ' '\n' | grep . | sort -g | awk '{a[NR]=$1} END {print (NR%2 ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2)}'; }
p=$(echo "${times[plain]}" | median)
for mode in plain tls verify; do
  m=$(echo "${times[$mode]}" | median)
  printf "%-7s median %.2f s  ratio to plain %.3f\n" "$mode" "$m" "$(echo "$m / $p" | bc -l)"
done
