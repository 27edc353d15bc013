#!/usr/bin/env bash
# Check dvc.yaml with a real DVC in a scratch clone (needs `pip install -e '.[dvc]'`; minutes of compute):
#   1. `dvc repro` on a fresh clone runs every stage;
#   2. a second `dvc repro` runs nothing;
#   3. changing one param (differentiate.gate_sigmas) reruns differentiate and what is downstream, not ingest/sync.
# Usage: bench/dvc_repro.sh [SCRATCH_DIR]
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
scratch="${1:-$(mktemp -d)}"
command -v dvc >/dev/null || { echo "dvc is not installed: pip install -e '.[dvc]'" >&2; exit 2; }
git clone -q "$repo" "$scratch/clone"
cd "$scratch/clone"
dvc init -q
echo "== 1. fresh clone: dvc repro"
time dvc repro 2>&1 | tee "$scratch/first.log" | grep -E "^(Running stage|Stage .* didn't change)" || true
for stage in example ingest sync features train decoupled simulate report; do
    grep -q "Running stage '$stage'" "$scratch/first.log" || { echo "FAIL: $stage did not run" >&2; exit 1; }
done
echo "== 2. second dvc repro: nothing to do"
dvc repro 2>&1 | tee "$scratch/second.log" | tail -3
if grep -q "Running stage" "$scratch/second.log"; then echo "FAIL: second repro ran stages" >&2; exit 1; fi
echo "== 3. change differentiate.gate_sigmas: only downstream reruns"
sed -i "s/^differentiate: {}$/differentiate: {gate_sigmas: 4.0}/" params.yaml
grep -q "gate_sigmas: 4.0" params.yaml || { echo "FAIL: could not edit params.yaml" >&2; exit 1; }
dvc repro 2>&1 | tee "$scratch/third.log" | grep -E "^Running stage" || true
for stage in example ingest sync; do
    if grep -q "Running stage '$stage'" "$scratch/third.log"; then echo "FAIL: $stage reran" >&2; exit 1; fi
done
grep -q "Running stage 'differentiate'" "$scratch/third.log" || { echo "FAIL: differentiate did not rerun" >&2; exit 1; }
dvc metrics show
echo "OK: dvc.yaml behaves (scratch: $scratch)"
