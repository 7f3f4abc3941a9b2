#!/usr/bin/env bash
# Re-create reports/vendor/: the JavaScript of report.html's 3D viewer, committed so that any
# machine builds a report offline with Python alone (docs/ARCHITECTURE.md, "The report's 3D viewer").
# Needs node and npm (the npm registry); run it only to change a pinned version below, then commit
# reports/vendor/. Writes:
#   three.bundle.min.js      three.js + OrbitControls, GLTFLoader, DRACOLoader (three-entry.js),
#                            bundled and minified by esbuild into one classic script (global THREE)
#   draco_wasm_wrapper.js    Google's Draco decoder (its full build, as three.js ships it)
#   draco_decoder.wasm
#   LICENSE.three.txt        three.js's MIT licence; LICENSE.draco.txt: the Apache-2.0 text
#   vendor.json              versions, licences and the SHA-256 of each file (reports/viewer_assets.py checks them)
set -euo pipefail
cd "$(dirname "$0")/.."
THREE_VERSION=0.187.0
ESBUILD_VERSION=0.28.2
APACHE_TEXT=${APACHE_TEXT:-/usr/share/common-licenses/Apache-2.0}   # Debian's copy of the licence text
out=reports/vendor
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && npm init -y >/dev/null && npm install --no-audit --no-fund --save-exact \
  "three@$THREE_VERSION" "esbuild@$ESBUILD_VERSION" >/dev/null)
cp "$out/three-entry.js" "$tmp/entry.js"
# import.meta.url: DRACOLoader derives default decoder paths from it, which the viewer replaces
# (an IIFE has no import.meta); the constant is never fetched.
"$tmp/node_modules/.bin/esbuild" "$tmp/entry.js" --bundle --format=iife --global-name=THREE --minify \
  --legal-comments=none --log-level=warning \
  '--define:import.meta.url="file:///three/examples/jsm/loaders/DRACOLoader.js"' \
  --outfile="$out/three.bundle.min.js"
draco="$tmp/node_modules/three/examples/jsm/libs/draco"   # the full build: the glTF build decodes no point sets
cp "$draco/draco_wasm_wrapper.js" "$draco/draco_decoder.wasm" "$out/"
cp "$tmp/node_modules/three/LICENSE" "$out/LICENSE.three.txt"
cp "$APACHE_TEXT" "$out/LICENSE.draco.txt"
python3 - "$out" "$THREE_VERSION" "$ESBUILD_VERSION" <<'PY'
import hashlib, json, sys
from pathlib import Path
out, three, esbuild = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
files = ["three.bundle.min.js", "draco_wasm_wrapper.js", "draco_decoder.wasm", "LICENSE.three.txt", "LICENSE.draco.txt"]
record = {
    "three": {"title": f"three.js {three}", "npm": f"three@{three}", "version": three, "license": "MIT", "license_file": "LICENSE.three.txt",
              "bundled_with": f"esbuild@{esbuild}", "entry": "three-entry.js"},
    "draco": {"title": f"Draco decoder (Google), as shipped in three@{three}", "npm": f"three@{three}",
              "path": "examples/jsm/libs/draco/", "license": "Apache-2.0", "license_file": "LICENSE.draco.txt"},
    "sha256": {f: hashlib.sha256((out / f).read_bytes()).hexdigest() for f in files},
}
(out / "vendor.json").write_text(json.dumps(record, indent=2) + "\n")
PY
echo "vendor_three.sh: reports/vendor/ holds three.js $THREE_VERSION (bundled with esbuild $ESBUILD_VERSION)"
