#!/usr/bin/env bash
# The two virtual environments of the Franka bridge's end-to-end test (bridge/README.md,
# "Franka"), from PyPI, idempotent:
#   .venv-franka-sim  franka-sim (a libfranka protocol server on MuJoCo; it pins numpy 1.26
#                     and mujoco < 3.3, so it cannot share legws' .venv) and the Panda's
#                     MJCF and meshes of robosuite's wheel (legws' .assets/panda when there,
#                     else from the wheel; franka-sim fetches its own FR3 model from GitHub
#                     at first use, which this machine cannot reach)
#   .venv-franka      the robot PC's side: pylibfranka and zenoh, as bridge/franka_bridge.py
#                     needs them
# Usage: bridge/franka/setup-venvs.sh [ROOT]   (ROOT: where the venvs go, default the
# repository). Rebuilt when the pins below change; a failed build leaves no stamp.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=${1:-$(cd "$HERE/../.." && pwd)}
PYTHON=${PYTHON:-python3}
export PIP_DISABLE_PIP_VERSION_CHECK=1

FRANKA_SIM="franka-sim==1.1.7"
PYLIBFRANKA="pylibfranka==0.21.3"
ZENOH="eclipse-zenoh==1.10.2"
ROBOSUITE="robosuite==1.5.2"  # only its wheel's robots/panda folder is kept
PINS="$FRANKA_SIM $PYLIBFRANKA $ZENOH $ROBOSUITE"

# PIP: a pip (>= 22.3) to install with (``$PIP --python VENV/bin/python``): the venvs are
# then made without a pip of their own (~5 s each); unset, each gets its own. UV: a uv to
# install with instead (``$UV pip install --python VENV/bin/python``: ~2 s where pip takes
# ~20 s), when it is there; the model's download still takes pip.
PIP=${PIP:-}
UV=${UV:-}

pip_in() {  # pip_in VENV ARGS...: pip for that venv
  local venv=$1; shift
  if [ -n "$PIP" ]; then "$PIP" --python "$venv/bin/python" "$@"; else "$venv/bin/pip" "$@"; fi
}

install_in() {  # install_in VENV PACKAGES...
  local venv=$1; shift
  if [ -n "$UV" ] && [ -x "$UV" ]; then "$UV" pip install -q --python "$venv/bin/python" "$@"
  else pip_in "$venv" install -q "$@"; fi
}

build() {  # build VENV PACKAGES...: a fresh venv with the packages, then the stamp
  local venv=$1; shift
  local stamp="$venv/.legws-franka"
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$PINS" ]; then return 0; fi
  echo "franka: building $venv" >&2
  rm -rf "$venv"
  if [ -n "$PIP" ]; then "$PYTHON" -m venv --without-pip "$venv"; else "$PYTHON" -m venv "$venv"; fi
  install_in "$venv" "$@"
  "${EXTRA:-true}" "$venv"
  echo "$PINS" > "$stamp"
}

panda_model() {  # the Panda MJCF (robot.xml, meshes) under VENV/share/legws-panda
  local venv=$1 tmp assets=${LEGWS_ASSETS:-$ROOT/.assets}/panda
  if [ -f "$assets/robot.xml" ] && [ -d "$assets/meshes" ] && [ -d "$assets/obj_meshes" ]; then
    # legws' own copy of the same folder (`legws assets fetch`): no 157 MB download
    mkdir -p "$venv/share/legws-panda"
    cp -r "$assets/robot.xml" "$assets/meshes" "$assets/obj_meshes" "$venv/share/legws-panda/"
    return 0
  fi
  tmp=$(mktemp -d)
  pip_in "$venv" download -q --no-deps -d "$tmp" "$ROBOSUITE" || { rm -rf "$tmp"; return 1; }
  "$venv/bin/python" - "$tmp"/robosuite-*.whl "$venv/share/legws-panda" <<'PY'
import sys, zipfile
from pathlib import Path, PurePosixPath
wheel, out = sys.argv[1], Path(sys.argv[2])
prefix = "robosuite/models/assets/robots/panda/"
with zipfile.ZipFile(wheel) as z:
    for name in z.namelist():
        if not name.startswith(prefix) or name.endswith("/"):
            continue
        rel = PurePosixPath(name[len(prefix):])
        if rel.is_absolute() or ".." in rel.parts:
            raise SystemExit(f"unsafe name in the wheel: {name!r}")
        target = out.joinpath(*rel.parts)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(z.read(name))
if not (out / "robot.xml").is_file():
    raise SystemExit("robosuite's wheel has no robots/panda/robot.xml")
PY
  local status=$?
  rm -rf "$tmp"
  return $status
}

EXTRA=panda_model build "$ROOT/.venv-franka-sim" "$FRANKA_SIM"
EXTRA=true build "$ROOT/.venv-franka" "$PYLIBFRANKA" "$ZENOH"
