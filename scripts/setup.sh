#!/usr/bin/env bash
# Set up AVS on this machine, idempotently: system libraries (apt when root, else a message of
# what to install), a virtualenv in .venv (or $AVS_VENV) and the project in it. Sourced by
# scripts/run and scripts/test; a second run only checks and returns in a second.
set -euo pipefail

AVS_ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
AVS_VENV=${AVS_VENV:-$AVS_ROOT/.venv}
AVS_PYTHON=${AVS_PYTHON:-python3}
export AVS_ROOT AVS_VENV

say() { printf '[avs setup] %s\n' "$*" >&2; }

# -- system libraries ---------------------------------------------------------------------------
# library file : Debian/Ubuntu package. Open3D: libusb, libGL, libgomp. MuJoCo headless: EGL on
# Mesa (libEGL_mesa + the software rasteriser in the DRI drivers).
declare -A LIBS=(
  [libusb-1.0.so.0]=libusb-1.0-0
  [libGL.so.1]=libgl1
  [libgomp.so.1]=libgomp1
  [libEGL.so.1]=libegl1
  [libEGL_mesa.so.0]=libegl-mesa0
  [libgallium]=libgl1-mesa-dri
)
missing=()
for lib in "${!LIBS[@]}"; do
  if ! ldconfig -p 2>/dev/null | grep -q "$lib"; then
    # the DRI/gallium drivers are not in the linker cache on every release: look for the files
    if [ "$lib" = libgallium ] && compgen -G "/usr/lib/*/dri/swrast_dri.so" >/dev/null; then
      continue
    fi
    missing+=("${LIBS[$lib]}")
  fi
done
if ! "$AVS_PYTHON" -c 'import sys; assert sys.version_info >= (3, 10)' 2>/dev/null; then
  say "AVS needs Python >= 3.10 as '$AVS_PYTHON' (set AVS_PYTHON to another interpreter)."
  exit 1
fi
if ! "$AVS_PYTHON" -c 'import venv, ensurepip' 2>/dev/null; then
  ver=$("$AVS_PYTHON" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
  missing+=("python$ver-venv")
fi
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    say "installing system packages: ${missing[*]}"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    say "AVS needs these system packages: ${missing[*]}"
    say "install them with:  sudo apt-get install ${missing[*]}"
    exit 1
  fi
fi

# -- virtualenv and packages --------------------------------------------------------------------
if [ ! -x "$AVS_VENV/bin/python" ]; then
  say "creating the virtualenv $AVS_VENV"
  "$AVS_PYTHON" -m venv "$AVS_VENV"
fi
stamp="$AVS_VENV/.avs-installed"
want=$(cat "$AVS_ROOT/pyproject.toml" "$AVS_ROOT/constraints.txt" | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  say "installing Python packages into $AVS_VENV (the first time takes a few minutes)"
  "$AVS_VENV/bin/python" -m pip install --disable-pip-version-check -q --upgrade pip
  "$AVS_VENV/bin/python" -m pip install --disable-pip-version-check --progress-bar on \
    -c "$AVS_ROOT/constraints.txt" -e "$AVS_ROOT[dev,bench,realsense]"
  echo "$want" > "$stamp"
fi

# The Compose Specification's JSON Schema, for the static check of compose.yaml (no docker
# engine is needed). It ships inside Docker's own docker-compose wheel on PyPI.
compose_schema="$AVS_VENV/share/avs/compose_spec.json"
if [ ! -s "$compose_schema" ]; then
  say "fetching the Compose Specification JSON Schema"
  tmp=$(mktemp -d)
  "$AVS_VENV/bin/python" -m pip download --disable-pip-version-check -q --no-deps \
    docker-compose==1.29.2 -d "$tmp"
  mkdir -p "$(dirname "$compose_schema")"
  "$AVS_VENV/bin/python" - "$tmp" "$compose_schema" <<'PY'
import sys, zipfile, pathlib
wheel = next(pathlib.Path(sys.argv[1]).glob("docker_compose-*.whl"))
with zipfile.ZipFile(wheel) as z:
    pathlib.Path(sys.argv[2]).write_bytes(z.read("compose/config/compose_spec.json"))
PY
  rm -rf "$tmp"
fi

export MUJOCO_GL=${MUJOCO_GL:-egl}
