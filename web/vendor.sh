#!/bin/sh
# Vendors JavaScript packages from the npm registry, or (--check) verifies that the vendored files
# are byte-identical to the pinned releases. Nothing here has a build step: the browser loads these
# files as they are, so there is nothing to rebuild, only provenance to check. Needs npm (and the
# registry) only when run.
#
# - three.js, into web/public/vendor/three: the page's ES modules, through index.html's import map.
# - IWER (Meta's Immersive Web Emulation Runtime), into cli/tests/browser/vendor/iwer: an emulated
#   WebXR headset the browser tests install in the page. Test-only: never served by bounce.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
mode=${1:-vendor}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# vendor NAME VERSION INTEGRITY DEST FILES: FILES is "package-path vendored-path" lines, the
# vendored path relative to DEST (relative to the repository root).
vendor() {
    name=$1 version=$2 integrity=$3 dest="$root/$4" files=$5
    mkdir -p "$work/$name"
    (cd "$work/$name" && npm pack --silent "$name@$version" >/dev/null)
    tarball="$work/$name/$name-$version.tgz"
    got="sha512-$(openssl dgst -sha512 -binary "$tarball" | base64 -w0)"
    if [ "$got" != "$integrity" ]; then
        echo "$name@$version: tarball integrity $got, expected $integrity" >&2
        return 1
    fi
    tar xzf "$tarball" -C "$work/$name"
    echo "$files" | while read -r src dst; do
        [ -n "$src" ] || continue
        if [ "$mode" = "--check" ]; then
            if ! cmp -s "$work/$name/package/$src" "$dest/$dst"; then
                echo "$4/$dst differs from $name@$version's $src" >&2
                exit 1
            fi
        else
            mkdir -p "$(dirname "$dest/$dst")"
            cp "$work/$name/package/$src" "$dest/$dst"
        fi
    done || return 1
    # Nothing vendored that the list does not name.
    count=$(find "$dest" -type f | wc -l)
    listed=$(echo "$files" | grep -c .)
    if [ "$count" != "$listed" ]; then
        echo "$4 holds $count files, the list names $listed" >&2
        return 1
    fi
    echo "$name@$version: vendored files match ($mode)"
}

status=0
vendor three 0.187.0 \
    sha512-Qiu7R+Cmh8CstZsY1uJOSWnVlfo7ZtNLV7mF8Jltk3LB3AtDu9cRZlcnRKkAk8Y4z6KKw35z7Y7Urd7jWY8etA== \
    web/public/vendor/three "
build/three.core.js three.core.js
build/three.module.js three.module.js
LICENSE LICENSE
examples/jsm/loaders/GLTFLoader.js addons/loaders/GLTFLoader.js
examples/jsm/utils/BufferGeometryUtils.js addons/utils/BufferGeometryUtils.js
examples/jsm/utils/SkeletonUtils.js addons/utils/SkeletonUtils.js
examples/jsm/controls/OrbitControls.js addons/controls/OrbitControls.js
examples/jsm/webxr/VRButton.js addons/webxr/VRButton.js
" || status=1
vendor iwer 2.5.0 \
    sha512-grq7iMyWo4s2DYnATKLPPoAByhcNuwLjMHHOILrFU9q8EGHIEzHyUuq1mz+9Xqy6+xrYPn3Ho8Z9eymZCE+D6w== \
    cli/tests/browser/vendor/iwer "
build/iwer.min.js iwer.min.js
LICENSE LICENSE
" || status=1
exit $status
