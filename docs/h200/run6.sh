#!/bin/bash
# Device run 6 (session 13): the tensor-core product kernel. Engine tests first (the tensor
# kernel against its FP32 twin and the CPU), then bench engines tiled vs tensor.
set -u
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
export XDG_RUNTIME_DIR=/tmp/xdg; mkdir -p $XDG_RUNTIME_DIR
gunzip -f .devcarry/*.gz; chmod +x .devcarry/*
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv > $OUT/gpu.txt
B=$PWD/.devcarry/bounce
t() { echo "== $(date +%T) $*"; }
t tests
(cd engine && timeout 120 ../.devcarry/engine-it --test-threads 4 2>&1) > $OUT/engine-tests.txt; echo "engine tests rc=$?"
grep -E "test result|FAILED|panicked|tensor" $OUT/engine-tests.txt | head -30
t bake c2
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 --codec dense-f32 -o /tmp/c2.bounce > /dev/null 2>&1; echo "rc=$?"
t bench small
timeout 150 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384 --codecs bc1,bc4,dense-f32 --batches 1,8,64 --kernels tiled,tensor --repeat 5 --csv $OUT/engines-synth.csv > $OUT/engines-synth.txt 2>&1; echo "rc=$?"
grep -E "gpu:|not measured|refused" $OUT/engines-synth.txt | head
cut -d, -f1-4,7,12,13,14 $OUT/engines-synth.csv
t bench 32768
timeout 260 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 32768 --codecs bc1 --batches 1,8,64 --kernels tiled,tensor --repeat 3 --csv $OUT/engines-32768.csv > $OUT/engines-32768.txt 2>&1; echo "rc=$?"
cut -d, -f1-4,7,12,13,14 $OUT/engines-32768.csv
for R in 1 2 8; do
  t rows1=$R
  BOUNCE_GPU_ROWS1=$R timeout 70 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384 --codecs dense-f32,bc1 --batches 1 --repeat 7 --csv $OUT/rows$R.csv > /dev/null 2>&1; echo "rc=$?"
  cut -d, -f1-4,7,12,13 $OUT/rows$R.csv
done
t done
