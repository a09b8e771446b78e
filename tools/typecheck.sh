#!/usr/bin/env bash
# mypy on the core and drivers layers (configured in pyproject.toml). The repository keeps
# engine/, drivers/ and tools/ at its top and installs them as `stillpoint.*` through package-dir;
# mypy cannot follow an editable install's import hook, so it reads them through a temporary
# folder of links laid out as the installed package.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
tree="$(mktemp -d)"
trap 'rm -rf "$tree"' EXIT
mkdir "$tree/stillpoint"
ln -s "$root/_stillpoint/__init__.py" "$tree/stillpoint/__init__.py"
for part in engine drivers tools; do ln -s "$root/$part" "$tree/stillpoint/$part"; done
cd "$tree"
MYPYPATH="$tree" mypy --config-file "$root/pyproject.toml" --cache-dir "$root/.mypy_cache" \
    -p stillpoint.engine.core -p stillpoint.drivers "$@"
