#!/bin/bash
# Device run 9 (session 22): the engine's tests on current code, the one-set dense products
# measured warm (rows a workgroup 4, 1, 2, 8), the server on pandora and the Cornell box, then
# every codec at 4,096 and 16,384 rows.
set -u
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
export XDG_RUNTIME_DIR=/tmp/xdg; mkdir -p $XDG_RUNTIME_DIR
gunzip -f .devcarry/*.gz; chmod +x .devcarry/bounce .devcarry/engine-it
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm,clocks.sm,temperature.gpu,power.draw --format=csv > $OUT/gpu.txt; cat $OUT/gpu.txt
B=$PWD/.devcarry/bounce
S=$(date +%s)
t() { echo "== +$(( $(date +%s) - S ))s $*"; }
t tests
(cd engine && timeout 80 ../.devcarry/engine-it --test-threads 8 2>&1) > $OUT/engine-tests.txt; echo "rc=$?"
grep -E "test result|FAILED|panicked" $OUT/engine-tests.txt | head -12
t bakes
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 --codec dense-f32 -o /tmp/c2.bounce > $OUT/bake-c2.txt 2>&1; echo "c2 rc=$?"
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 -o /tmp/c2s.bounce > /dev/null 2>&1; echo "c2s rc=$?"
timeout 60 $B bake assets/pandora/pandora.glb --patches 4000 --codec dense-f32 -o /tmp/p4.bounce > $OUT/bake-p4.txt 2>&1; echo "p4 rc=$?"; tail -3 $OUT/bake-p4.txt
for R in 4 1 8; do
  t rows1=$R
  BOUNCE_GPU_ROWS1=$R timeout 45 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384 --codecs dense-f32,dense-f16 --batches 1 --repeat 9 --csv $OUT/rows$R.csv > /dev/null 2>&1; echo "rc=$?"
  cut -d, -f1-4,7,11-13 $OUT/rows$R.csv | tail -4
done
t serve
for E in gpu cpu; do
  timeout 25 $B bench serve /tmp/p4.bounce --engine $E --sessions 10 --viewers 1000 --csv $OUT/serve-p4-$E.csv > /dev/null 2>&1; echo "p4 $E rc=$?"; tail -1 $OUT/serve-p4-$E.csv
done
timeout 25 $B bench serve /tmp/c2s.bounce --engine gpu --sessions 10 --viewers 1000 --csv $OUT/serve-c2s-gpu.csv > /dev/null 2>&1; echo "c2s gpu rc=$?"; tail -1 $OUT/serve-c2s-gpu.csv
t pandora engines
timeout 60 $B bench engines /tmp/p4.bounce --engines gpu,cpu --codecs dense-f32,bc1 --batches 1,8,64 --repeat 5 --csv $OUT/engines-p4.csv > $OUT/engines-p4.txt 2>&1; echo "rc=$?"
cut -d, -f1-4,7,11-14 $OUT/engines-p4.csv
t synth 4096,16384 every codec
timeout 110 $B bench engines /tmp/c2.bounce --engines gpu,cpu --synthetic 4096,16384 --batches 1,8,64 --repeat 5 --csv $OUT/engines-synth.csv > $OUT/engines-synth.txt 2>&1; echo "rc=$?"
t done
