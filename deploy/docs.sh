#!/usr/bin/env bash
# Builds the book (docs/ -> docs/book/index.html: open it in a browser) with mdBook,
# installing mdBook first when this machine has not got it (from crates.io into
# ${MDBOOK_ROOT:-~/.cargo}/bin, about 2 minutes on 2 cores, once). A page named in SUMMARY.md
# but missing fails the build (create-missing = false); the links between pages and the
# generated reference pages are checked by the test suite (tests/tests/docs_links.rs and
# `mbpo docs --check`).
set -euo pipefail
cd "$(dirname "$0")/.."
MDBOOK_VERSION=0.5.4
root="${MDBOOK_ROOT:-$HOME/.cargo}"
mdbook=""
for candidate in "$(command -v mdbook || true)" "$root/bin/mdbook"; do
    if [ -x "$candidate" ] && "$candidate" --version | grep -q "v$MDBOOK_VERSION"; then
        mdbook="$candidate"
        break
    fi
done
if [ -z "$mdbook" ]; then
    echo "deploy/docs.sh: installing mdbook $MDBOOK_VERSION into $root/bin" >&2
    cargo install --locked --quiet mdbook --version "$MDBOOK_VERSION" \
        --no-default-features --features search --root "$root"
    mdbook="$root/bin/mdbook"
fi
"$mdbook" build docs
echo "deploy/docs.sh: the book is docs/book/index.html"
