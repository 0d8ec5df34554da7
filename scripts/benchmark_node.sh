#!/usr/bin/env bash
# Regenerates results/node_benchmark.md: latency from a relative-pose message
# to the keyframe's frame in tf2 (1,000 and 10,000 keyframes in the graph) and
# the relative-pose message rate the node takes in. Starts its own master on a
# private port, the node and the benchmark client, and stops them at the end.
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh
export ROS_MASTER_URI=http://127.0.0.1:11399
export ROS_HOSTNAME=127.0.0.1
SOLVE_PERIOD=0.05
rosmaster --core -p 11399 >/tmp/rotavg_bench_master.log 2>&1 &
MASTER=$!
trap 'kill $NODE $MASTER 2>/dev/null || true' EXIT
sleep 2
"$BIN/rotation_averaging_node" __name:=rotation_averaging _solve_period_s:=$SOLVE_PERIOD \
    _max_queue:=100000 >/tmp/rotavg_bench_node.log 2>&1 &
NODE=$!
"$BIN/rotavg_node_benchmark" _solve_period_s:=$SOLVE_PERIOD _output:=results/node_benchmark.md \
    "_command:=bash scripts/benchmark_node.sh"
