#!/usr/bin/env bash
# Creates (or refreshes) synthetic-scenes/.venv with the pinned Mitsuba 3 toolchain
# used to render the synthetic ground-truth scenes. Idempotent: a venv that already
# has the pinned versions is left alone.
#
#   bash synthetic-scenes/setup-venv.sh            # uses python3
#   PYTHON=/usr/bin/python3.11 bash synthetic-scenes/setup-venv.sh
#
# Prints the venv's python path on the last line of stdout.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="${EDGENERF_MITSUBA_VENV:-$HERE/.venv}"
PYTHON="${PYTHON:-python3}"
REQ="$HERE/requirements.txt"

if ! command -v "$PYTHON" >/dev/null 2>&1; then
    echo "setup-venv: '$PYTHON' not found; set PYTHON=/path/to/python3 (3.9 or newer)" >&2
    exit 1
fi

want_stamp="$(cat "$REQ")"
stamp="$VENV/.edgenerf-requirements"
if [ -x "$VENV/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want_stamp" ] \
    && "$VENV/bin/python" -c 'import mitsuba, drjit, numpy; mitsuba.set_variant("scalar_rgb")' >/dev/null 2>&1; then
    echo "setup-venv: $VENV is up to date" >&2
else
    if [ ! -x "$VENV/bin/python" ]; then
        echo "setup-venv: creating $VENV with $("$PYTHON" --version 2>&1)" >&2
        "$PYTHON" -m venv "$VENV"
    fi
    "$VENV/bin/python" -m pip install --disable-pip-version-check -q -r "$REQ"
    "$VENV/bin/python" -c 'import mitsuba; mitsuba.set_variant("scalar_rgb")'
    printf '%s' "$want_stamp" >"$stamp"
    echo "setup-venv: installed $(tr '\n' ' ' <"$REQ")into $VENV" >&2
fi
echo "$VENV/bin/python"
