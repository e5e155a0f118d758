#!/usr/bin/env bash
# A real two-node Ray cluster on this machine, driven through `python -m cluster render`:
#
#  1. starts a Ray head and a second Ray node as separate processes (`ray start --head`,
#     `ray start --address`), each with its own temp dir, 1 CPU and its own TMPDIR;
#  2. renders a quick scene as 4 shards through the driver (--address) and checks the merged
#     dataset byte-identical (diff -r) to a direct `xtask render`;
#  3. renders a heavier version again and, while one of its shard tasks runs on the second node,
#     kills that node's raylet (SIGKILL): Ray re-runs the lost task on the head, and the dataset
#     must still come out byte-identical, with no shard folder or partial file left in the
#     output; then restarts the second node and does the same with --shared-storage (the killed
#     shard's half-written folder is resumed by the retry);
#  4. stops the cluster (on any exit, through a trap).
#
# Installs nothing. Environment:
#   CLUSTER_PYTHON  a Python with cluster/requirements.txt installed (default .venv-cluster/bin/python;
#                   its `ray` script is used to start the nodes)
#   XTASK           the xtask binary (default target/debug/xtask)
#   SCENE           the scene (default tabletop)
#   KEEP=1          keep the work folder (datasets, Ray's logs) at the end
# Takes about 1.5 minutes on 2 cores. Exit status 0 when every check passes.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PY=${CLUSTER_PYTHON:-$ROOT/.venv-cluster/bin/python}
XTASK=${XTASK:-$ROOT/target/debug/xtask}
SCENE=${SCENE:-tabletop}
RAY=$(dirname "$PY")/ray
T0=$(date +%s)

say() { printf '[test_local_cluster %3ds] %s\n' "$(($(date +%s) - T0))" "$*" >&2; }
fail() {
    say "FAILED: $*"
    exit 1
}

[ -x "$PY" ] || fail "no Python at $PY: python3 -m venv .venv-cluster && .venv-cluster/bin/pip install -r cluster/requirements.txt (or set CLUSTER_PYTHON)"
[ -x "$RAY" ] || fail "no ray command beside $PY (is cluster/requirements.txt installed there?)"
[ -x "$XTASK" ] || fail "no xtask binary at $XTASK: cargo build -p xtask (or set XTASK)"
XTASK=$(cd "$(dirname "$XTASK")" && pwd)/$(basename "$XTASK")

# Ray's Unix socket paths live under the temp dirs and must stay short: /tmp, not $TMPDIR.
WORK=$(mktemp -d /tmp/nerf-ray.XXXXXX)
LOGS=$WORK/logs
mkdir "$LOGS"
# This cluster's own token (Ray 2.60 turns token authentication on when ~/.ray/auth_token exists),
# quick teardown, no usage reports.
export RAY_AUTH_MODE=token
RAY_AUTH_TOKEN=$("$PY" -c 'import secrets; print(secrets.token_hex(32))')
export RAY_AUTH_TOKEN
export RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S=0 RAY_USAGE_STATS_ENABLED=0
unset RAY_ADDRESS

NODES=()  # pids of the `ray start --block` processes, each leading its own process group
CHILD=    # the driver or xtask now running
OK=0

stop_node() {
    local pid=$1 i
    kill -TERM "$pid" 2>/dev/null || return 0
    for i in $(seq 50); do
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.2
    done
    # Whatever of that node outlived its `ray start` (same process group, started by us).
    kill -KILL -- "-$pid" 2>/dev/null || true
}

cleanup() {
    local rc=$? pid
    if [ -n "$CHILD" ] && kill -TERM "$CHILD" 2>/dev/null; then wait "$CHILD" 2>/dev/null || true; fi
    for pid in "${NODES[@]}"; do stop_node "$pid"; done
    if [ "$OK" = 1 ] && [ "${KEEP:-0}" != 1 ]; then
        rm -rf "$WORK"
    else
        say "work folder kept: $WORK (Ray's logs in */session_latest/logs)"
    fi
    say "cluster stopped; $([ "$OK" = 1 ] && echo PASSED || echo "FAILED (exit $rc)") in $(($(date +%s) - T0)) s"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# logged LOG CMD...: CMD run in the repository with its output in LOG; its exit status. In the
# background and waited for, so that a signal to this script is handled at once.
logged() {
    local log=$1
    shift
    (cd "$ROOT" && exec "$@") >"$log" 2>&1 &
    CHILD=$!
    wait "$CHILD"
}

# start_node NAME RAY-START-ARGS...: a node in the background, its pid in $NODE_PID.
start_node() {
    local name=$1
    shift
    mkdir -p "$WORK/$name-tmp"
    TMPDIR="$WORK/$name-tmp" setsid "$RAY" start --block --temp-dir="$WORK/$name" --disable-usage-stats --num-cpus=1 "$@" \
        >"$LOGS/$name.log" 2>&1 &
    NODE_PID=$!
    NODES+=("$NODE_PID")
    local i
    for i in $(seq 120); do
        grep -q "Ray runtime started" "$LOGS/$name.log" && return 0
        kill -0 "$NODE_PID" 2>/dev/null || break
        sleep 0.5
    done
    tail -20 "$LOGS/$name.log" >&2
    fail "Ray node '$name' did not start (log: $LOGS/$name.log)"
}

# wait_cpus N: until the cluster has N CPUs alive.
wait_cpus() {
    "$PY" - "$ADDRESS" "$1" <<'EOF' || fail "the cluster never showed $1 CPUs"
import logging, sys, time
import ray
ray.init(address=sys.argv[1], logging_level=logging.ERROR, log_to_driver=False)
want, t0 = float(sys.argv[2]), time.monotonic()
while ray.cluster_resources().get("CPU", 0) != want:
    if time.monotonic() - t0 > 60:
        sys.exit(1)
    time.sleep(0.5)
EOF
}

# the raylet of the node whose `ray start --block` is $1
raylet_of() { pgrep -P "$1" -f 'core/src/ray/raylet/raylet' | head -1; }

# an `xtask render` running in a Ray worker under raylet $1 (raylet -> worker -> xtask)
xtask_under() {
    local w
    for w in $(pgrep -P "$1"); do
        pgrep -P "$w" -f "render .*--shard" && return 0
    done
    return 1
}

# check_same OUT REF: OUT is REF byte for byte, and nothing of the driver's or the merge's is
# left beside it or in it (OUT.shards, .part folders, hidden .tmp files).
check_same() {
    diff -r "$2" "$1" >"$LOGS/diff.txt" 2>&1 || {
        head -20 "$LOGS/diff.txt" >&2
        fail "$1 differs from the direct render $2"
    }
    local left
    left=$(
        find "$1" \( -name '.*' -o -name '*.part' -o -name '*.tmp' \) -print
        find "$(dirname "$1")" -maxdepth 1 \( -name "$(basename "$1")?*" -o -name ".$(basename "$1")*" \) -print
    )
    [ -z "$left" ] || fail "left behind by the render into $1: $left"
    say "$1 is byte-identical to the direct render ($(find "$1" -type f | wc -l) files), nothing else left"
}

PORT=$("$PY" -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')
ADDRESS=127.0.0.1:$PORT
say "work folder $WORK; starting the head (1 CPU) on port $PORT"
start_node head --head --port="$PORT" --include-dashboard=false
say "starting the second node (1 CPU)"
start_node worker --address="$ADDRESS"
WORKER=$NODE_PID
wait_cpus 2
say "cluster up: 2 nodes, 2 CPUs"

DRIVER=("$PY" -m cluster render "$SCENE" --address "$ADDRESS" --xtask "$XTASK" --shards 4 --max-retries 3)

# --- 1: four shards through the object store, merged, against a direct render -------------------
QUICK=(--preset quick)
say "render 1: $SCENE ${QUICK[*]}, 4 shards"
logged "$LOGS/r1.log" "${DRIVER[@]}" --out "$WORK/r1" "${QUICK[@]}" || {
    tail -30 "$LOGS/r1.log" >&2
    fail "render 1 failed (log: $LOGS/r1.log)"
}
grep -q "shard .* done" "$LOGS/r1.log" || fail "render 1 reported no shard"
logged "$LOGS/ref1.log" "$XTASK" render "$SCENE" --out "$WORK/ref1" "${QUICK[@]}" || fail "xtask render failed (log: $LOGS/ref1.log)"
check_same "$WORK/r1" "$WORK/ref1"

# --- 2, 3: the second node's raylet killed while it renders a shard --------------------------
# 256 samples: each shard's task runs ~5 s on 1 core, long enough to be caught running.
HEAVY=(--preset quick --spp 256)
logged "$LOGS/ref2.log" "$XTASK" render "$SCENE" --out "$WORK/ref2" "${HEAVY[@]}" || fail "xtask render failed (log: $LOGS/ref2.log)"

# render_with_kill NAME DRIVER-ARGS...: renders while the second node's raylet is killed mid-shard.
render_with_kill() {
    local name=$1 raylet xpid i
    shift
    raylet=$(raylet_of "$WORKER") || true
    [ -n "$raylet" ] || fail "no raylet under the second node's ray start ($WORKER)"
    say "render $name: $SCENE ${HEAVY[*]}, 4 shards $*; will kill the second node's raylet (pid $raylet) mid-shard"
    (cd "$ROOT" && exec "${DRIVER[@]}" --out "$WORK/$name" "${HEAVY[@]}" "$@") >"$LOGS/$name.log" 2>&1 &
    local driver=$!
    CHILD=$driver
    xpid=
    for i in $(seq 300); do
        xpid=$(xtask_under "$raylet") && break
        kill -0 "$driver" 2>/dev/null || break
        sleep 0.1
    done
    [ -n "$xpid" ] || {
        wait "$driver" || true
        tail -30 "$LOGS/$name.log" >&2
        fail "no shard task ever ran on the second node"
    }
    sleep 1
    kill -0 "$xpid" 2>/dev/null || fail "the shard on the second node finished before the kill (make its shards heavier)"
    local what
    what=$(ps -o args= -p "$xpid" | grep -o -- '--shard [0-9]*/[0-9]*' || true)
    kill -KILL "$raylet"
    say "killed the second node's raylet while its xtask (pid $xpid, ${what:-a shard}) was rendering"
    for i in $(seq 50); do
        kill -0 "$xpid" 2>/dev/null || break
        sleep 0.1
    done
    ! kill -0 "$xpid" 2>/dev/null || fail "the killed node's xtask (pid $xpid) outlived its worker"
    wait "$driver" || {
        tail -30 "$LOGS/$name.log" >&2
        fail "render $name did not survive the lost node (log: $LOGS/$name.log)"
    }
    [ "$(grep -c 'shard [0-9]/4 done' "$LOGS/$name.log")" = 4 ] || fail "render $name: not 4 shards done"
    check_same "$WORK/$name" "$WORK/ref2"
}

render_with_kill r2
say "restarting the second node"
wait "$WORKER" 2>/dev/null || true # its `ray start --block` ends once its raylet is gone
start_node worker2 --address="$ADDRESS"
WORKER=$NODE_PID
wait_cpus 2
render_with_kill r3 --shared-storage

OK=1
