#!/usr/bin/env bash
# The cluster path, run for real (docs/cluster.md): a single-node SLURM cluster from Debian's packages
# (munge, MariaDB, slurmdbd, slurmctld, slurmd) on this machine runs the workflow through
# `snakemake --profile profiles/slurm` on a small test configuration, and the check then
#   - requires every job of the run to have ended COMPLETED in sacct,
#   - compares the run's tables with those of a local `snakemake -j1` run of the same configuration,
#   - runs a copy of the configuration with a bad value, whose jobs must end FAILED in sacct and whose
#     error Snakemake must report,
#   - prints each job's SLURM id, rule, state, elapsed time, CPU time and peak memory, and the CPU share
#     of Snakemake's own process in both runs.
# Every service it starts is stopped on exit, also on failure. Needs root (apt-get, daemons).
#
#   bash scripts/slurm-check.sh          # after scripts/bootstrap.sh
#
# Settings (environment): DPSI_SLURM_SCRATCH, the folder for everything the check writes (default
# /tmp/dpsi-slurm-check, emptied at the start); DPSI_SLURM_CONFIG, the workflow configuration (default
# tests/data/cluster.yaml, 26 jobs; tests/data/tiny.yaml runs every rule, 96 jobs); DPSI_SLURM_TARGET
# (default tables); DPSI_SLURM_PORT, the first of the four TCP ports on 127.0.0.1 the daemons use (default
# 16817). Besides the scratch folder it writes only the symbolic link /etc/slurm/slurm.conf to its
# configuration (the jobs' own srun calls read that path), removed on exit, and refuses to run if that
# path is anything else.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT=$PWD
SCRATCH=${DPSI_SLURM_SCRATCH:-/tmp/dpsi-slurm-check}
CONFIG=$(realpath "${DPSI_SLURM_CONFIG:-tests/data/cluster.yaml}")
TARGET=${DPSI_SLURM_TARGET:-tables}
PORT=${DPSI_SLURM_PORT:-16817}
CLUSTER=dpsicheck
ACCOUNT=dpsi
PARTITION=check
PYTHON=$ROOT/.venv/bin/python
SYSTEM_CONF=/etc/slurm/slurm.conf
RUN=$SCRATCH/run      # sockets and pid files
ETC=$SCRATCH/etc      # slurm.conf, slurmdbd.conf
LOG=$SCRATCH/log      # the daemons' logs
SERVICES=(munged mysqld slurmdbd slurmctld slurmd)  # started in this order, stopped in the reverse

say() { echo "slurm-check: $*"; }
fail() { echo "slurm-check: FAILED: $*" >&2; exit 1; }

# --- what is missing gets installed ------------------------------------------------------------------

install_packages() {
    local missing=()
    command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v sacct >/dev/null || missing+=(slurm-wlm)
    command -v slurmdbd >/dev/null || missing+=(slurmdbd)
    command -v munged >/dev/null || missing+=(munge)
    command -v mariadbd >/dev/null || missing+=(mariadb-server)
    if [ ${#missing[@]} -gt 0 ]; then
        say "installing ${missing[*]}"
        local out
        if ! out=$(export DEBIAN_FRONTEND=noninteractive; apt-get update -qq 2>&1 &&
                   apt-get install -y -qq "${missing[@]}" 2>&1); then
            fail "cannot install the Debian packages ${missing[*]} (apt-get said: $(tail -n 3 <<<"$out"))"
        fi
    fi
    [ -x "$PYTHON" ] || fail "no $PYTHON: run scripts/bootstrap.sh first"
    if ! "$PYTHON" -c "import snakemake_executor_plugin_slurm" 2>/dev/null; then
        say "installing the Snakemake SLURM executor plugin (pip install -e '.[slurm]')"
        "$PYTHON" -m pip install -q -e '.[slurm]' ||
            fail "cannot install snakemake-executor-plugin-slurm into .venv (pip install -e '.[slurm]')"
    fi
}

# --- services ------------------------------------------------------------------------------------------

stop_services() {
    local i name pid
    if [ -f "$RUN/slurmctld.pid" ] && kill -0 "$(cat "$RUN/slurmctld.pid")" 2>/dev/null; then
        SLURM_CONF=$ETC/slurm.conf scancel -u "$(id -un)" 2>/dev/null || true  # jobs outlive slurmd
        for _ in $(seq 60); do
            [ -z "$(SLURM_CONF=$ETC/slurm.conf squeue -h 2>/dev/null)" ] && break
            sleep 1
        done
    fi
    for ((i = ${#SERVICES[@]} - 1; i >= 0; i--)); do
        name=${SERVICES[i]}
        [ -f "$RUN/$name.pid" ] || continue
        pid=$(cat "$RUN/$name.pid")
        if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
            kill "$pid" 2>/dev/null || true
            for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
            kill -0 "$pid" 2>/dev/null && kill -9 "$pid" 2>/dev/null
            say "stopped $name (pid $pid)"
        fi
        rm -f "$RUN/$name.pid"
    done
    if [ -L "$SYSTEM_CONF" ] && [ "$(readlink "$SYSTEM_CONF")" = "$ETC/slurm.conf" ]; then
        rm -f "$SYSTEM_CONF"
    fi
}

# wait_for WHAT SECONDS LOGFILE COMMAND...: retry COMMAND until it succeeds, or fail showing LOGFILE's end.
wait_for() {
    local what=$1 seconds=$2 logfile=$3
    shift 3
    for _ in $(seq $((seconds * 2))); do
        "$@" >/dev/null 2>&1 && return 0
        sleep 0.5
    done
    tail -n 20 "$logfile" >&2 || true
    fail "$what did not come up within $seconds s (its log: $logfile)"
}

write_configs() {
    local host mem_mb
    host=$(hostname -s)
    # The node offers what slurmd finds, less 1 GiB for the daemons and the Snakemake process.
    mem_mb=$(($(slurmd -C | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p') - 1024))
    cat >"$ETC/slurm.conf" <<EOF
# Written by scripts/slurm-check.sh: a single-node cluster on this machine.
ClusterName=$CLUSTER
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=root
AuthType=auth/munge
AuthInfo=socket=$RUN/munge.socket
# the munge socket of messages to slurmdbd
AccountingStoragePass=$RUN/munge.socket
StateSaveLocation=$SCRATCH/state
SlurmdSpoolDir=$SCRATCH/spool
SlurmctldPidFile=$RUN/slurmctld.pid
SlurmdPidFile=$RUN/slurmd.pid
SlurmctldLogFile=$LOG/slurmctld.log
SlurmdLogFile=$LOG/slurmd.log
# no cgroups in a container: processes tracked through /proc, CPUs bound by affinity
ProctrackType=proctrack/linuxproc
TaskPlugin=task/affinity
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=5
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=127.0.0.1
AccountingStoragePort=$((PORT + 2))
AccountingStorageEnforce=associations
AccountingStoreFlags=job_comment
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
MpiDefault=none
ReturnToService=2
MinJobAge=600
NodeName=$host NodeAddr=127.0.0.1 CPUs=$(nproc) RealMemory=$mem_mb State=UNKNOWN
PartitionName=$PARTITION Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
    cat >"$ETC/slurmdbd.conf" <<EOF
AuthType=auth/munge
AuthInfo=socket=$RUN/munge.socket
DbdHost=$host
DbdAddr=127.0.0.1
DbdPort=$((PORT + 2))
SlurmUser=root
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$((PORT + 3))
StorageUser=slurm
StoragePass=dpsi-slurm-check
StorageLoc=slurm_acct_db
PidFile=$RUN/slurmdbd.pid
LogFile=$LOG/slurmdbd.log
EOF
    chmod 600 "$ETC/slurmdbd.conf"
}

start_services() {
    mkdir -p "$RUN" "$ETC" "$LOG" "$SCRATCH/state" "$SCRATCH/spool" "$SCRATCH/db"
    mkdir -m 700 "$SCRATCH/munge"
    chmod 755 "$SCRATCH" "$RUN"   # munged wants every folder above its socket searchable
    write_configs
    export SLURM_CONF=$ETC/slurm.conf
    ln -s "$ETC/slurm.conf" "$SYSTEM_CONF"

    dd if=/dev/urandom of="$SCRATCH/munge/munge.key" bs=1024 count=1 status=none
    chmod 400 "$SCRATCH/munge/munge.key"
    munged --key-file="$SCRATCH/munge/munge.key" --socket="$RUN/munge.socket" \
        --pid-file="$RUN/munged.pid" --log-file="$LOG/munged.log" --seed-file="$SCRATCH/munge/seed"
    wait_for munged 10 "$LOG/munged.log" munge -S "$RUN/munge.socket" -n

    mariadb-install-db --no-defaults --datadir="$SCRATCH/db" --auth-root-authentication-method=socket \
        --skip-test-db >"$LOG/mariadb-install.log" 2>&1 || fail "mariadb-install-db (log: $LOG/mariadb-install.log)"
    mariadbd --no-defaults --user=root --datadir="$SCRATCH/db" --socket="$RUN/mysqld.sock" \
        --pid-file="$RUN/mysqld.pid" --bind-address=127.0.0.1 --port=$((PORT + 3)) --skip-name-resolve \
        --innodb-buffer-pool-size=256M --innodb-lock-wait-timeout=900 --log-error="$LOG/mariadb.log" \
        </dev/null >/dev/null 2>&1 &
    wait_for MariaDB 60 "$LOG/mariadb.log" mariadb-admin --no-defaults -S "$RUN/mysqld.sock" -u root ping
    mariadb --no-defaults -S "$RUN/mysqld.sock" -u root -e \
        "CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY 'dpsi-slurm-check';
         GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';"

    slurmdbd
    wait_for slurmdbd 60 "$LOG/slurmdbd.log" sacctmgr -n list cluster
    sacctmgr -i add cluster "$CLUSTER" >/dev/null
    sacctmgr -i add account "$ACCOUNT" Description="DPSI check" Organization=dpsi >/dev/null
    sacctmgr -i add user "$(id -un)" Account="$ACCOUNT" >/dev/null

    slurmctld
    wait_for slurmctld 60 "$LOG/slurmctld.log" scontrol ping
    slurmd
    wait_for "the node" 60 "$LOG/slurmd.log" bash -c "sinfo -h -o %T | grep -qx idle"
    say "cluster up: $(sinfo -h -o '%P %D node(s) %c CPUs %m MB %T')"
}

# --- the runs ------------------------------------------------------------------------------------------

# measured NAME FOLDER SNAKEMAKE-ARGS...: run Snakemake in FOLDER under scripts/cpu_share.py (the CPU
# time of its own process beside its children's), its output in $SCRATCH/NAME.log.
measured() {
    local name=$1 folder=$2
    shift 2
    mkdir -p "$folder"
    local start=$SECONDS rc=0
    "$PYTHON" scripts/cpu_share.py --json "$SCRATCH/$name.cpu.json" -- \
        "$ROOT/.venv/bin/snakemake" --snakefile "$ROOT/Snakefile" --directory "$folder" \
        --configfile "$1" "${@:2}" >"$SCRATCH/$name.log" 2>&1 || rc=$?
    say "$name: exit $rc after $((SECONDS - start)) s (output: $SCRATCH/$name.log)"
    return $rc
}

slurm_run_id() {  # the executor plugin names every job of a run after the run's id
    sed -n 's/.*SLURM run ID: \([0-9a-f-]*\).*/\1/p' "$1" | head -n 1
}

main() {
    [ "$(id -u)" = 0 ] || fail "needs root: it installs packages and starts the cluster's daemons"
    if [ -e "$SYSTEM_CONF" ] || [ -L "$SYSTEM_CONF" ]; then
        [ -L "$SYSTEM_CONF" ] && [[ "$(readlink "$SYSTEM_CONF")" == "$SCRATCH"/* ]] ||
            fail "$SYSTEM_CONF exists: this machine has a SLURM configuration of its own, which the check will not replace"
    fi
    install_packages
    stop_services   # those a killed earlier check left running
    rm -rf "$SCRATCH"
    mkdir -p "$SCRATCH"
    trap stop_services EXIT
    trap 'exit 130' INT TERM
    start_services

    local slurm_args=(--profile "$ROOT/profiles/slurm" --slurm-init-seconds-before-status-checks 5
                      --seconds-between-status-checks 5)
    export SBATCH_PARTITION=$PARTITION SBATCH_ACCOUNT=$ACCOUNT
    measured slurm "$SCRATCH/slurm-run" "$CONFIG" "${slurm_args[@]}" "$TARGET" ||
        { tail -n 40 "$SCRATCH/slurm.log" >&2; fail "the SLURM run failed"; }
    measured local "$SCRATCH/local-run" "$CONFIG" -j1 "$TARGET" ||
        { tail -n 40 "$SCRATCH/local.log" >&2; fail "the local run failed"; }

    say "jobs of the SLURM run:"
    "$PYTHON" scripts/slurm_check.py jobs --name "$(slurm_run_id "$SCRATCH/slurm.log")" --state COMPLETED \
        --json "$SCRATCH/slurm-jobs.json" || fail "not every job of the SLURM run COMPLETED"
    say "tables, SLURM run against the local run:"
    "$PYTHON" scripts/slurm_check.py compare "$SCRATCH/local-run" "$SCRATCH/slurm-run" ||
        fail "the SLURM run's tables differ from the local run's"
    say "Snakemake's own CPU time:"
    "$PYTHON" scripts/slurm_check.py share --local "$SCRATCH/local.cpu.json" \
        --slurm "$SCRATCH/slurm.cpu.json" --slurm-jobs "$SCRATCH/slurm-jobs.json"

    # A bad value that passes the schema: identification refuses the datapoints (more particles than
    # max_particles). In the finished run's folder only the jobs with simulator settings are redone.
    "$PYTHON" scripts/slurm_check.py bad-config "$CONFIG" "$SCRATCH/bad.yaml"
    if measured bad "$SCRATCH/slurm-run" "$SCRATCH/bad.yaml" "${slurm_args[@]}" --keep-going "$TARGET"; then
        fail "the run with the bad configuration succeeded"
    fi
    grep -q "Error in rule identify" "$SCRATCH/bad.log" ||
        fail "Snakemake did not report the failing rule (see $SCRATCH/bad.log)"
    grep -rq "more than the simulator's max_particles=100" "$SCRATCH/slurm-run" --include='*.log' ||
        fail "no job log holds the error of the bad configuration"
    say "jobs of the run with a bad value (simulator.max_particles: 100):"
    "$PYTHON" scripts/slurm_check.py jobs --name "$(slurm_run_id "$SCRATCH/bad.log")" --rule identify \
        --state FAILED || fail "the identification jobs of the run with a bad value did not end FAILED"
    say "passed: every job of the SLURM run COMPLETED, its tables match the local run's, the bad run's identification FAILED"
}

if [ "${BASH_SOURCE[0]}" = "$0" ]; then main "$@"; exit; fi   # sourced: only the functions
