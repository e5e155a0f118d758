#!/usr/bin/env bash
# Browser end-to-end test of `xtask view` in headless Chromium (not in CI: see docs/viewer.md).
#   apt-get install -y chromium chromium-driver
#   bash tests/viewer/run.sh        # about 3 minutes on 2 cores after the build
# (it makes tests/viewer/.venv with selenium and pillow from PyPI when it is missing)
# It renders a tiny dataset, trains a run for 20 s, opens the viewer on it, drags the view and
# checks from screenshots that the scene is drawn and changes; then trains a second run for
# 30 s with a viewer open on its folder and checks that the curves and a checkpoint appear.
# SCREENSHOT=docs/images/viewer.png also writes the page's screenshot there.
set -euo pipefail
cd "$(dirname "$0")/../.."
XTASK=${XTASK:-./target/debug/xtask}
PY=${PY:-tests/viewer/.venv/bin/python}
OUT=${OUT:-out/viewer-e2e}
if [ ! -x "$PY" ]; then
  python3 -m venv tests/viewer/.venv
  tests/viewer/.venv/bin/pip install --quiet selenium pillow
  PY=tests/viewer/.venv/bin/python
fi
rm -rf "$OUT"
mkdir -p "$OUT"
pids=()
trap 'for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done' EXIT

"$XTASK" render tabletop --out "$OUT/data" --preset quick --res 64 --train 24 --val 2 --test 2 --spp 8 2>/dev/null
"$XTASK" train "$OUT/data" --out "$OUT/run" --model fast --time 20s 2>/dev/null

# Prints the URL a viewer started in the background announces on stdout.
start_viewer() {
  "$XTASK" view "$1" --port 0 > "$2" 2>/dev/null &
  pids+=($!)
  for _ in $(seq 100); do
    url=$(grep -o 'http://[^ ]*' "$2" || true)
    [ -n "$url" ] && { echo "$url"; return; }
    sleep 0.1
  done
  echo "viewer did not start" >&2; exit 1
}

url=$(start_viewer "$OUT/run" "$OUT/view1.log")
"$PY" tests/viewer/e2e.py trained "$url" "$OUT"

# A run being trained: the viewer opens on its empty folder first, waits, then follows it.
mkdir -p "$OUT/live"
python3 - "$OUT/run/config.json" "$OUT/live.json" <<'PYEOF'
import json, sys
c = json.load(open(sys.argv[1]))
c["checkpoint_interval_steps"] = 25
c["log_interval_steps"] = 10
json.dump(c, open(sys.argv[2], "w"))
PYEOF
url=$(start_viewer "$OUT/live" "$OUT/view2.log")
"$XTASK" train --config "$OUT/live.json" --out "$OUT/live" --time 30s 2>/dev/null &
trainer=$!
pids+=($trainer)
"$PY" tests/viewer/e2e.py live "$url" "$OUT" "$OUT/live" "$trainer" "${SCREENSHOT:-}"
echo "viewer e2e: passed"
