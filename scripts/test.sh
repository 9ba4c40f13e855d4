#!/usr/bin/env bash
# Install everything (scripts/setup.sh) and run the test suite. Extra arguments go to pytest.
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh || exit 1
PY=${PYTHON:-python3}
"$PY" -m pytest -q "$@"
rc=$?
# pytest exit 5 = no tests collected (e.g. a -k filter matched nothing): not a failure.
if [ $rc -eq 5 ]; then echo "test.sh: pytest collected no tests" >&2; exit 0; fi
exit $rc
