#!/bin/bash
# Device run 7 (session 13): tests with the f16 tolerances, the tensor kernel's probes (no decode,
# no products) and the staggered column walk of the matrix-vector kernels.
set -u
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
export XDG_RUNTIME_DIR=/tmp/xdg; mkdir -p $XDG_RUNTIME_DIR
gunzip -f .devcarry/*.gz; chmod +x .devcarry/*
B=$PWD/.devcarry/bounce
t() { echo "== $(date +%T) $*"; }
t tests
(cd engine && timeout 120 ../.devcarry/engine-it --test-threads 4 2>&1) > $OUT/engine-tests.txt; echo "engine tests rc=$?"
grep -E "test result|FAILED|panicked" $OUT/engine-tests.txt | head -10
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 --codec dense-f32 -o /tmp/c2.bounce > /dev/null 2>&1; echo "bake rc=$?"
for P in 0 1 2; do
  t probe $P
  BOUNCE_GPU_TENSOR_PROBE=$P timeout 60 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 16384 --codecs bc1 --batches 64 --kernels tensor --repeat 5 --csv $OUT/probe$P.csv > /dev/null 2>&1; echo "rc=$?"
  cut -d, -f1-4,7 $OUT/probe$P.csv | tail -1
done
for S in 0 1; do
  t stagger $S
  BOUNCE_GPU_STAGGER=$S timeout 70 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384 --codecs dense-f32,bc1 --batches 1,8 --kernels tiled --repeat 7 --csv $OUT/stagger$S.csv > /dev/null 2>&1; echo "rc=$?"
  cut -d, -f1-4,7,12,13 $OUT/stagger$S.csv | tail -8
done
t done
