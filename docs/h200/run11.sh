#!/bin/bash
# Device run 11, prepared in session 22 for the next session with a GPU (not yet run). Carry
# `.gl` (the Vulkan loader, see the device README) and `.devcarry` (the release `bounce`,
# stripped and gzipped), and run `bash docs/h200/run11.sh`. What run 10 left open, first:
# kernel times of lit against all columns at 32,768 rows (run 10 saw lit slower by wall, measured
# first), then dense-f32's one-set share of bandwidth there, then pandora's one-channel
# transport with 4 and 8 rows a workgroup, and (session 23) pandora's direct light under a sky
# on both engines. Files go into one archive (at most
# 8 files come back from a call).
set -u
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
export XDG_RUNTIME_DIR=/tmp/xdg; mkdir -p $XDG_RUNTIME_DIR
gunzip -f .devcarry/*.gz; chmod +x .devcarry/bounce
B=$PWD/.devcarry/bounce
W=/tmp/run11; mkdir -p $W
S=$(date +%s)
t() { echo "== +$(( $(date +%s) - S ))s $*"; }
pack() { (cd /tmp && tar czf $OUT/run11.tar.gz run11); }
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 --codec dense-f32 -o /tmp/c2.bounce > /dev/null 2>&1; echo "c2 rc=$?"
t 32768 dense-f32 lit vs all
timeout 150 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 32768 --codecs dense-f32 --batches 1,8 --columns lit,all --repeat 9 --csv $W/engines-32768-dense.csv > $W/engines-32768-dense.txt 2>&1; echo "rc=$?"
cut -d, -f1-4,7,11-14 $W/engines-32768-dense.csv
pack
t 4096 16384 lit vs all, dense-f32 and bc1
timeout 120 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384 --codecs dense-f32,bc1 --batches 1,8 --columns lit,all --repeat 9 --csv $W/engines-synth.csv > $W/engines-synth.txt 2>&1; echo "rc=$?"
cut -d, -f1-4,7,11-14 $W/engines-synth.csv
pack
t pandora rows a workgroup
# pandora's transport is one channel: a thread of the one-set kernel has 4 loads in flight a
# column step where three channels give it 12, which may be why it read 23% of the bandwidth
# where the three-channel synthetic matrices read 53%. More rows a workgroup restore the loads.
timeout 60 $B bake assets/pandora/pandora.glb --patches 4000 --codec dense-f32 -o /tmp/p4.bounce > /dev/null 2>&1; echo "p4 rc=$?"
for R in 4 8; do
  BOUNCE_GPU_ROWS1=$R timeout 60 $B bench engines /tmp/p4.bounce --engines gpu --codecs dense-f32 --batches 1 --columns lit,all --repeat 9 --csv $W/rows$R-p4.csv > /dev/null 2>&1; echo "rows $R rc=$?"
  grep dense-f32 $W/rows$R-p4.csv | cut -d, -f1-4,7,11-14
done
pack
t pandora under a sky
# Session 23 moved the sky's near-field correction onto the device (run 10: a sky took the GPU's
# direct light on pandora from 0.71 to 9.48 ms a set, computed on the host). The bench's
# `+ sky` rows measure the same sets with a uniform sky added, in the same run.
timeout 90 $B bench engines /tmp/p4.bounce --engines gpu,cpu --codecs dense-f32 --batches 1,8 --repeat 5 --csv $W/sky-p4.csv > $W/sky-p4.txt 2>&1; echo "sky rc=$?"
cat $W/sky-p4.txt | tail -20
pack
t done
