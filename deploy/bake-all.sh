#!/bin/sh
# Bake every glTF scene under a directory into another, one baked file per scene:
#   IN/NAME.gltf, IN/NAME.glb, IN/NAME/<any>.gltf|glb  ->  OUT/NAME.bounce
# The compose file's one-shot `bake` service runs this before the server starts; CI runs it on
# the Cornell box (cli/tests/deploy.rs).
#
#   bounce-bake-all [IN [OUT]]      IN: $BOUNCE_SCENES_IN or /scenes; OUT: $BOUNCE_SCENES or /baked
#
# Extra `bounce bake` flags come from $BOUNCE_BAKE_ARGS (split on spaces). A baked file newer than
# its scene is kept unless BOUNCE_REBAKE=1. With no scene in IN, $BOUNCE_DEMO_SCENE (the image's
# Cornell box) is baked as cornell-box, so the server has something to serve.
set -eu

in="${1:-${BOUNCE_SCENES_IN:-/scenes}}"
out="${2:-${BOUNCE_SCENES:-/baked}}"
bounce="${BOUNCE_BIN:-bounce}"
extra="${BOUNCE_BAKE_ARGS:-}"

mkdir -p "$out"
baked=" "
count=0

bake_one() { # SCENE NAME
  case "$baked" in
    *" $2 "*)
      echo "bounce-bake-all: two scenes are named '$2' (the second is $1): rename one" >&2
      exit 1 ;;
  esac
  baked="$baked$2 "
  count=$((count + 1))
  target="$out/$2.bounce"
  if [ "${BOUNCE_REBAKE:-0}" != 1 ] && [ -f "$target" ] && [ "$target" -nt "$1" ]; then
    echo "bounce-bake-all: $target is newer than $1, kept (BOUNCE_REBAKE=1 bakes it again)"
    return
  fi
  echo "bounce-bake-all: baking $1 into $target"
  # shellcheck disable=SC2086 # the extra flags are meant to split
  "$bounce" bake "$1" -o "$target" --quiet $extra
}

for f in "$in"/*.gltf "$in"/*.glb; do
  [ -f "$f" ] || continue
  name=$(basename "$f")
  bake_one "$f" "${name%.*}"
done
for f in "$in"/*/*.gltf "$in"/*/*.glb; do
  [ -f "$f" ] || continue
  bake_one "$f" "$(basename "$(dirname "$f")")"
done

if [ "$count" -eq 0 ]; then
  demo="${BOUNCE_DEMO_SCENE:-}"
  if [ -n "$demo" ] && [ -f "$demo" ]; then
    echo "bounce-bake-all: no scene in $in; baking the demo Cornell box"
    bake_one "$demo" cornell-box
  else
    echo "bounce-bake-all: no .gltf or .glb scene in $in (nor a demo scene)" >&2
    exit 1
  fi
fi
echo "bounce-bake-all: $count scene(s) in $out"
