#!/bin/sh
# The rosbag import measured end to end: a 1300-frame sim dataset, its training frames written as ROS 2 bags by the
# Python `rosbags` package (rgb8 images at 10 Hz, joint states at 50 Hz; MCAP and SQLite3),
# imported with `msr import-bag`; then `msr train` + `msr quantize` + `msr eval` on the imported
# dataset and on the folder dataset, both evaluated on the folder dataset's marked test split.
# usage: host/bench/rosbag_vs_folder.sh WORKDIR [COUNT]   (from the repository root, after
# `cargo build --release -p msr-host` and `cargo xtask setup`)
set -eu
W=$1
N=${2:-1300}
MSR=target/release/msr
PY=target/pyenv/bin/python
mkdir -p "$W"
t() { /usr/bin/time -f "%e s wall, %U s user: $*" "$@"; }
[ -f "$W/ds/dataset.json" ] || t $MSR dataset --count "$N" --out "$W/ds"
for s in mcap sqlite3; do
  rm -rf "$W/bag_$s" "$W/imp_$s"
  t $PY host/tests/rosbag/write_bag.py "$W/ds" "$W/bag_$s" --storage $s --encoding rgb8 --split train
  t $MSR import-bag "$W/bag_$s" --image-topic /camera/image_raw --joints-topic /joint_states \
      --template "$W/ds/template.png" --out "$W/imp_$s" --test-fraction 0
done
echo "imported datasets, MCAP against SQLite3:"; diff -r "$W/imp_mcap" "$W/imp_sqlite3" && echo identical
[ -f "$W/reach.safetensors" ] || t $MSR train-reach --inputs "$W/ds/reach_centroids.csv" --targets "$W/ds/reach_joints.csv" --out "$W/reach.safetensors"
for d in ds imp_mcap; do
  rm -rf "$W/train_$d"
  t $MSR train --data "$W/$d" --out "$W/train_$d"
  t $MSR quantize --train "$W/train_$d" --reach "$W/reach.safetensors" --out "$W/$d.msrm"
  $MSR eval --model "$W/$d.msrm" --data "$W/ds" --json > "$W/eval_$d.json"
  $MSR eval --model "$W/$d.msrm" --data "$W/ds"
done
