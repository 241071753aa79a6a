#!/bin/sh
# Vendors three.js into web/public/vendor/three from the npm registry, or (--check) verifies that
# the vendored files are byte-identical to the pinned release. The page has no build step: the
# browser loads these ES modules as they are, through index.html's import map, so there is
# nothing to rebuild, only provenance to check. Needs npm (and the registry) only when run.
set -eu
VERSION=0.187.0
INTEGRITY=sha512-Qiu7R+Cmh8CstZsY1uJOSWnVlfo7ZtNLV7mF8Jltk3LB3AtDu9cRZlcnRKkAk8Y4z6KKw35z7Y7Urd7jWY8etA==
# package path -> vendored path (relative to web/public/vendor/three)
FILES="
build/three.core.js three.core.js
build/three.module.js three.module.js
LICENSE LICENSE
examples/jsm/loaders/GLTFLoader.js addons/loaders/GLTFLoader.js
examples/jsm/utils/BufferGeometryUtils.js addons/utils/BufferGeometryUtils.js
examples/jsm/utils/SkeletonUtils.js addons/utils/SkeletonUtils.js
examples/jsm/controls/OrbitControls.js addons/controls/OrbitControls.js
examples/jsm/webxr/VRButton.js addons/webxr/VRButton.js
"
here=$(cd "$(dirname "$0")" && pwd)
dest="$here/public/vendor/three"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
npm pack --silent "three@$VERSION" >/dev/null
tarball="three-$VERSION.tgz"
got="sha512-$(openssl dgst -sha512 -binary "$tarball" | base64 -w0)"
if [ "$got" != "$INTEGRITY" ]; then
    echo "three@$VERSION: tarball integrity $got, expected $INTEGRITY" >&2
    exit 1
fi
tar xzf "$tarball"
status=0
echo "$FILES" | while read -r src dst; do
    [ -n "$src" ] || continue
    if [ "${1:-}" = "--check" ]; then
        if ! cmp -s "package/$src" "$dest/$dst"; then
            echo "web/public/vendor/three/$dst differs from three@$VERSION's $src" >&2
            exit 1
        fi
    else
        mkdir -p "$(dirname "$dest/$dst")"
        cp "package/$src" "$dest/$dst"
    fi
done || status=1
# Nothing vendored that the list does not name.
count=$(find "$dest" -type f | wc -l)
listed=$(echo "$FILES" | grep -c .)
if [ "$count" != "$listed" ]; then
    echo "web/public/vendor/three holds $count files, the list names $listed" >&2
    status=1
fi
[ "$status" = 0 ] && echo "three@$VERSION: vendored files match (${1:-vendored})"
exit $status
