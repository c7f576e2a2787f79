#!/bin/sh
# Rebuilds wart-editor.js (CodeMirror 6 and the page's glue, one file) from editor-src/.
# The committed wart-editor.js is what the page runs; this needs npm only to rebuild it.
set -eu
cd "$(dirname "$0")/editor-src"
npm ci --no-audit --no-fund
node_modules/.bin/esbuild editor.js --bundle --minify --format=iife --target=es2020 \
  --legal-comments=none --outfile=../wart-editor.js
node licences.js > ../wart-editor.LICENSES.txt
echo "built $(wc -c < ../wart-editor.js) bytes"
