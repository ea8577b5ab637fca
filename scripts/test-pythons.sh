#!/usr/bin/env bash
# `make test-pythons`: the suite under the oldest and newest Pythons rigcal supports, so syntax
# or an API that one version lacks fails here, not at a user's. Each version gets its own
# .venv-X.Y (rebuilt when pyproject.toml changes). The `slow` tests (end-to-end renders and
# calibrations, 10 s or more each) and the `browser` tests run only under `make test`;
# everything else runs here too, so every module's own tests see both Pythons. A version
# that is not installed is skipped with a line saying so.
set -uo pipefail
cd "$(dirname "$0")/.."
status=0
for v in ${RIGCAL_PYTHONS:-3.10 3.13}; do
  py=""
  if command -v pyenv >/dev/null 2>&1; then
    py=$(ls -d "$(pyenv root)"/versions/"$v".*/bin/python 2>/dev/null | sort -V | tail -n 1)
  fi
  [ -n "$py" ] || py=$(command -v "python$v" 2>/dev/null || true)
  if [ -z "$py" ]; then
    echo "Python $v: skipped, not installed (no pyenv version $v.*, no python$v on the PATH)"
    continue
  fi
  venv=".venv-$v"
  if [ ! -f "$venv/.installed" ] || [ pyproject.toml -nt "$venv/.installed" ]; then
    echo "Python $v: installing rigcal into $venv ($py)"
    rm -rf "$venv"
    "$py" -m venv "$venv" && "$venv/bin/python" -m pip install -q --upgrade pip \
      && "$venv/bin/python" -m pip install -q -e '.[test]' && touch "$venv/.installed" \
      || { echo "Python $v: install failed"; status=1; continue; }
  fi
  echo "Python $v: $("$venv/bin/python" --version), numpy $("$venv/bin/python" -c 'import numpy; print(numpy.__version__)')"
  "$venv/bin/python" -m pytest -q -p no:cacheprovider -n auto --dist loadfile -m "not slow and not browser" || status=1
done
exit $status
