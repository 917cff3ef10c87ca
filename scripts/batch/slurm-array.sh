#!/bin/bash
# Foothold-safety reports over an archive of scans as a Slurm job array (docs/batch.md).
# Each array task runs shard SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN of 8 (`--shard 8` reads
# both), so --array=0-7 and --array=1-8 both work; all tasks write into one shared folder.
# Submit with:   sbatch scripts/batch/slurm-array.sh /shared/scans /shared/reports
# Re-submit the same command after a failure or a pre-emption: --resume skips committed scans.
#SBATCH --job-name=terrastride-report
#SBATCH --array=0-7
#SBATCH --cpus-per-task=1
#SBATCH --mem=2G
#SBATCH --time=02:00:00
#SBATCH --requeue
#SBATCH --output=terrastride-report-%A_%a.log
set -u
SCANS=${1:?usage: sbatch slurm-array.sh SCANS_DIR_OR_MANIFEST OUT_DIR}
OUT=${2:?usage: sbatch slurm-array.sh SCANS_DIR_OR_MANIFEST OUT_DIR}
TERRASTRIDE=${TERRASTRIDE:-terrastride}
"$TERRASTRIDE" report --batch "$SCANS" --out "$OUT" --shard 8 --resume
code=$?
# 0: every scan of this shard reported; 3: some failed (listed in OUT/index.json); 1/2: not run.
if [ "$code" -eq 3 ]; then echo "some scans failed; see $OUT/index.json" >&2; fi
exit "$code"
