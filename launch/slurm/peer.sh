#!/bin/bash
# One sph peer of a SLURM job (called by sph.sbatch through srun; one call per task).
#
# Reads SLURM_PROCID (rank), SLURM_NTASKS (world), SLURM_LOCALID, SLURM_NTASKS_PER_NODE or
# SLURM_TASKS_PER_NODE, SLURM_JOB_NODELIST, SLURM_JOB_ID, SLURM_CPUS_PER_TASK. Overrides:
#   SPH_PYTHON      Python with sphfluid installed (default: python3)
#   SPH_BASE_PORT   first port on every node (default: 7447)
#   SPH_NODES       space-separated node names, in SLURM order (default: scontrol show hostnames)
#   SPH_LISTEN_HOST address to listen on (default: this task's node name, as the others dial it)
#   SPH_TLS         the job's credentials folder (sph.sbatch makes it with `sph certs`; required
#                   unless SPH_INSECURE=1)
#   SPH_INSECURE    1: plain TCP, no authentication (refused unless every node is a loopback address)
set -euo pipefail
config=${1:?usage: peer.sh SCENE.toml [sph peer options]}
shift
rank=${SLURM_PROCID:?not inside a SLURM task (SLURM_PROCID is unset)}
world=${SLURM_NTASKS:?SLURM_NTASKS is unset}
base=${SPH_BASE_PORT:-7447}
per_node=${SLURM_NTASKS_PER_NODE:-${SLURM_TASKS_PER_NODE%%(*}}
per_node=${per_node%%,*}
if [ -n "${SPH_NODES:-}" ]; then
    read -r -a nodes <<< "$SPH_NODES"
else
    mapfile -t nodes < <(scontrol show hostnames "$SLURM_JOB_NODELIST")
fi
if [ $(( ${#nodes[@]} * per_node )) -lt "$world" ]; then
    echo "peer.sh: $world tasks do not fit ${#nodes[@]} nodes x $per_node tasks per node" >&2
    exit 2
fi
local_id=$(( rank % per_node ))
if [ "${SPH_INSECURE:-0}" = 1 ]; then
    scheme=tcp; security=(--insecure)
else
    scheme=tls; security=(--tls "${SPH_TLS:?SPH_TLS is unset: make the credentials of the job with sph certs, as sph.sbatch does}")
fi
me=${nodes[$(( rank / per_node ))]}
args=(--rank "$rank" --world "$world" --run-id "slurm-${SLURM_JOB_ID:-0}" "${security[@]}"
      --listen "$scheme/${SPH_LISTEN_HOST:-$me}:$(( base + local_id ))")
for (( r = 0; r < rank; r++ )); do   # connect to every lower rank: a full mesh
    args+=(--zenoh "$scheme/${nodes[$(( r / per_node ))]}:$(( base + r % per_node ))")
done
if [ -n "${SLURM_CPUS_PER_TASK:-}" ]; then
    args+=(--threads "$SLURM_CPUS_PER_TASK")
fi
if [ "$rank" != 0 ]; then
    args+=(--quiet)
fi
# -P: the installed sphfluid, never a launch/ or sphcore/ folder in the submit folder (sphcore/children.py)
exec "${SPH_PYTHON:-python3}" -P -m launch.cli peer "$config" "${args[@]}" "$@"
