#!/bin/sh
# Check stillpoint's MCAP outputs with Foxglove's TypeScript reader (@mcap/core, indexed reader).
#
#     tools/check_mcap_ts.sh [FILE.mcap ...]
#
# Without files: simulates a 6 h AX3 pair (25 Hz) and writes the outputs of `process` (batch
# and online with a prior), `replay`, `recover` (of a torn copy) and `align -o` into a scratch
# folder, then reads them all. Needs node and npm: installs @mcap/core and @mcap/support (for
# the zstd/lz4 decompressors) into the scratch folder, never into the repository.
# Exit code 0 when every file reads; 1 otherwise.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
scratch=${STILLPOINT_TS_SCRATCH:-${TMPDIR:-/tmp}/stillpoint_mcap_ts}
mkdir -p "$scratch"
command -v node >/dev/null || { echo "node not found: cannot run the TypeScript reader" >&2; exit 2; }
if [ ! -d "$scratch/node_modules/@mcap/core" ]; then
  (cd "$scratch" && npm init -y >/dev/null && npm install --silent --no-audit --no-fund @mcap/core @mcap/support >/dev/null)
fi
echo "@mcap/core $(node -p "require('$scratch/node_modules/@mcap/core/package.json').version"), node $(node --version)"
if [ "$#" -eq 0 ]; then
  d="$scratch/outputs"
  rm -rf "$d" && mkdir -p "$d"
  sp="python -m stillpoint.tools"
  $sp simulate -o "$d/wrist.cwa" --pair hip --days 0.25 --hz 25 --seed 3 >/dev/null
  $sp process "$d/wrist.cwa" -o "$d/batch.mcap" -q
  python - "$d" <<'PY'
import json, sys
from stillpoint.engine.calibration.estimate import CalibrationEstimate
est = CalibrationEstimate(offset=[0.01, -0.02, 0.03], scale=[1.0, 1.0, 1.0], status="ok",
                          method="autocal-c1", fit_end_ns=1_600_000_000 * 10**9)
open(sys.argv[1] + "/prior.json", "w").write(json.dumps(est.to_dict()))
PY
  $sp process "$d/wrist.cwa" -o "$d/online.mcap" --mode online --prior "$d/prior.json" -q
  $sp replay "$d/batch.mcap" -o "$d/replay.mcap" --check -q >/dev/null
  python -c "import sys; b=open(sys.argv[1],'rb').read(); open(sys.argv[2],'wb').write(b[:len(b)//2])" \
    "$d/batch.mcap" "$d/torn.mcap.part"
  $sp recover "$d/torn.mcap.part" -o "$d/recovered.mcap" >/dev/null
  hip=$(ls "$d"/*hip*.cwa | head -1)
  $sp align "$d/wrist.cwa" "$hip" -o "$d/align.mcap" >/dev/null || true  # too short to align: still logs
  set -- "$d/batch.mcap" "$d/online.mcap" "$d/replay.mcap" "$d/recovered.mcap" "$d/align.mcap"
fi
cp "$here/check_mcap_ts.mjs" "$scratch/check_mcap_ts.mjs"
node "$scratch/check_mcap_ts.mjs" "$@"
