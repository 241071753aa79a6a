#!/bin/bash
# Device run 10 (session 22): the matrix-vector kernels skip dark column groups. Engine tests,
# then lit against all columns on the same uploads: synthetic 4,096 / 16,384 / 32,768 (dense-f32,
# bc1, batches 1, 8, 64 with the tiled and tensor kernels), pandora's own transport, the server.
set -u
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
export XDG_RUNTIME_DIR=/tmp/xdg; mkdir -p $XDG_RUNTIME_DIR
gunzip -f .devcarry/*.gz; chmod +x .devcarry/bounce .devcarry/engine-it
B=$PWD/.devcarry/bounce
W=/tmp/run10; mkdir -p $W
S=$(date +%s)
t() { echo "== +$(( $(date +%s) - S ))s $*"; }
pack() { (cd /tmp && tar czf $OUT/run10.tar.gz run10); }
t tests
(cd engine && timeout 80 ../.devcarry/engine-it --test-threads 8 2>&1) > $W/engine-tests.txt; echo "rc=$?"
grep -E "test result|FAILED|panicked|dark_column" $W/engine-tests.txt | head -12
t bakes
timeout 40 $B bake assets/cornell-box/scene.gltf --patches 2000 --codec dense-f32 -o /tmp/c2.bounce > /dev/null 2>&1; echo "c2 rc=$?"
timeout 60 $B bake assets/pandora/pandora.glb --patches 4000 --codec dense-f32 -o /tmp/p4.bounce > /dev/null 2>&1; echo "p4 rc=$?"
pack
t pandora lit vs all
timeout 50 $B bench engines /tmp/p4.bounce --engines gpu,cpu --codecs dense-f32 --batches 1,8 --columns lit,all --repeat 9 --csv $W/engines-p4.csv > $W/engines-p4.txt 2>&1; echo "rc=$?"
grep -E "^ *(gpu|cpu)" $W/engines-p4.txt | grep dense | cut -c1-200
pack
t serve p4 gpu
timeout 25 $B bench serve /tmp/p4.bounce --engine gpu --sessions 10 --viewers 1000 --csv $W/serve-p4-gpu.csv > /dev/null 2>&1; echo "rc=$?"; cat $W/serve-p4-gpu.csv
pack
t synth lit vs all
timeout 210 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384,32768 --codecs dense-f32,bc1 --batches 1,8,64 --columns lit,all --repeat 5 --csv $W/engines-synth.csv > $W/engines-synth.txt 2>&1; echo "rc=$?"
grep -E "^ *gpu" $W/engines-synth.txt | cut -c1-200
pack
t synth f16 resid
timeout 70 $B bench engines /tmp/c2.bounce --engines gpu --synthetic 4096,16384 --codecs dense-f16,bc1-resid --batches 1,8,64 --repeat 5 --csv $W/engines-synth2.csv > $W/engines-synth2.txt 2>&1; echo "rc=$?"
grep -E "^ *gpu" $W/engines-synth2.txt | cut -c1-200
pack
t done
