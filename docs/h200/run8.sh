#!/bin/bash
# Device run 8 (session 13): the tensor kernel's probes again, now that bench engines warms up
# for half a second (run 7's probes ran on a cold GPU), then 32,768 rows tiled vs tensor.
set -u
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
export XDG_RUNTIME_DIR=/tmp/xdg; mkdir -p $XDG_RUNTIME_DIR
gunzip -f .devcarry/*.gz; chmod +x .devcarry/*
B=$PWD/.devcarry/bounce
t() { echo "== $(date +%T) $*"; }
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 --codec dense-f32 -o /tmp/c2.bounce > /dev/null 2>&1; echo "bake rc=$?"
for P in 0 1 2; do
  t probe $P
  K=tensor; [ $P = 0 ] && K=tiled,tensor
  BOUNCE_GPU_TENSOR_PROBE=$P timeout 50 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 16384 --codecs bc1 --batches 1,64 --kernels $K --repeat 5 --csv $OUT/probe$P.csv > /dev/null 2>&1; echo "rc=$?"
  cut -d, -f1-4,7 $OUT/probe$P.csv | tail -3
done
t 32768
timeout 120 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 32768 --codecs bc1 --batches 1,64 --kernels tiled,tensor --repeat 3 --csv $OUT/engines-32768.csv > $OUT/engines-32768.txt 2>&1; echo "rc=$?"
cut -d, -f1-4,7,12,13,14 $OUT/engines-32768.csv
t done
