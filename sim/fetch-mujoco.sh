#!/usr/bin/env bash
# Fetches MuJoCo 3.17.0's shared library from the PyPI wheel `mujoco==3.17.0` (the version
# mujoco-rs 7 binds) and prints the `export` lines that build and run `--features sim`:
#
#     eval "$(sim/fetch-mujoco.sh)" && cargo build --release --features sim
#
# Idempotent: a second run finds the library and only prints the lines. Progress goes to
# stderr, so that stdout is only the lines to eval. Where it goes: $MARIONETTE_MUJOCO_DIR,
# else target/mujoco-3.17.0 in this repository. Needs python3 with pip (the wheel is a zip).
set -euo pipefail
version=3.17.0
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
dir=${MARIONETTE_MUJOCO_DIR:-$repo/target/mujoco-$version}
lib=$dir/libmujoco.so.$version

if [ ! -f "$lib" ]; then
    mkdir -p "$dir"
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
    echo "fetch-mujoco: downloading the mujoco==$version wheel from PyPI" >&2
    python3 -m pip download --quiet --no-deps --only-binary=:all: "mujoco==$version" -d "$work" >&2
    wheel=$(ls "$work"/mujoco-"$version"-*.whl | head -n 1)
    python3 - "$wheel" "$lib" <<'PY'
import shutil, sys, zipfile
wheel, dest = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(wheel) as z:
    names = [n for n in z.namelist() if n.endswith("/libmujoco.so.3.17.0")]
    if not names:
        sys.exit(f"fetch-mujoco: {wheel} holds no libmujoco.so.3.17.0")
    with z.open(names[0]) as src, open(dest + ".part", "wb") as out:
        shutil.copyfileobj(src, out)
shutil.move(dest + ".part", dest)
PY
    echo "fetch-mujoco: $lib" >&2
fi
ln -sfn "libmujoco.so.$version" "$dir/libmujoco.so"
echo "export MUJOCO_DYNAMIC_LINK_DIR=\"$dir\""
echo "export LD_LIBRARY_PATH=\"$dir\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}\""
