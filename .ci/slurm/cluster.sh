#!/usr/bin/env bash
# A one-node SLURM cluster on localhost for `make test-slurm`, entirely inside one directory:
# munged, MariaDB, slurmdbd (accounting: the executor plugin polls job states with sacct),
# slurmctld and slurmd, all as root, cgroup-less (proctrack/linuxproc, task/none).
#
#   .ci/slurm/cluster.sh install        Debian packages (non-interactive; skipped when present)
#   .ci/slurm/cluster.sh start DIR      write configs under DIR, start the daemons, wait for idle
#   .ci/slurm/cluster.sh stop DIR       stop every daemon started from DIR (safe to repeat)
#
# After start, `export SLURM_CONF=DIR/etc/slurm.conf` points sbatch/sacct/sinfo at the cluster.
# Ports are not SLURM's defaults, so a system cluster on the machine is left alone.
set -euo pipefail

CPUS=${SLURM_TEST_CPUS:-2}
MEM_MB=${SLURM_TEST_MEM_MB:-4096}
PORT_CTLD=16817 PORT_SLURMD=16818 PORT_DBD=16819 PORT_DB=16806
MUNGE_SOCKET=/run/munge/munge.socket.2
PACKAGES=(munge mariadb-server slurmdbd slurmctld slurmd slurm-client)

log() { echo "==> [slurm] $*"; }

install() {
    local missing=()
    for p in "${PACKAGES[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    if ((${#missing[@]} == 0)); then
        log "Debian packages already installed: ${PACKAGES[*]}"
        return
    fi
    log "installing ${missing[*]} (apt-get, non-interactive)"
    export DEBIAN_FRONTEND=noninteractive
    # policy-rc.d 101 keeps the packages' own services (system munge, mariadb, slurm) stopped:
    # the test runs its own daemons from its own directory.
    local policy=/usr/sbin/policy-rc.d created=0
    if [[ ! -e $policy ]]; then
        printf '#!/bin/sh\nexit 101\n' >"$policy" && chmod +x "$policy" && created=1
    fi
    local rc=0
    { apt-get update -qq && apt-get install -y -q --no-install-recommends "${missing[@]}"; } || rc=$?
    ((created)) && rm -f "$policy"
    return $rc
}

# wait_for SECONDS DESCRIPTION COMMAND...: poll until COMMAND succeeds.
wait_for() {
    local seconds=$1 what=$2
    shift 2
    local deadline=$((SECONDS + seconds))
    until "$@" >/dev/null 2>&1; do
        if ((SECONDS >= deadline)); then
            log "timed out after ${seconds}s waiting for $what"
            return 1
        fi
        sleep 0.5
    done
}

write_configs() {
    local d=$1
    mkdir -p "$d"/{etc,log,run,state,spool,munge,db}
    chmod 700 "$d/munge"
    dd if=/dev/urandom of="$d/munge/munge.key" bs=1024 count=1 status=none
    chmod 400 "$d/munge/munge.key"
    cat >"$d/etc/slurm.conf" <<CONF
ClusterName=enclab
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$PORT_CTLD
SlurmdPort=$PORT_SLURMD
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
StateSaveLocation=$d/state
SlurmdSpoolDir=$d/spool
SlurmctldPidFile=$d/run/slurmctld.pid
SlurmdPidFile=$d/run/slurmd.pid
SlurmctldLogFile=$d/log/slurmctld.log
SlurmdLogFile=$d/log/slurmd.log
PlugStackConfig=$d/etc/plugstack.conf
# No cgroups: works in containers and on machines without a delegated cgroup tree.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
AccountingStoragePort=$PORT_DBD
JobCompType=jobcomp/none
ReturnToService=2
SlurmdParameters=config_overrides
# Configless: slurmd fetches this file from slurmctld and caches it in /run/slurm/conf, where
# commands inside a job (srun, run by the plugin with SLURM_* variables removed) find it.
SlurmctldParameters=enable_configless
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$CPUS RealMemory=$MEM_MB State=UNKNOWN
PartitionName=main Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
    : >"$d/etc/plugstack.conf"
    cat >"$d/etc/slurmdbd.conf" <<CONF
AuthType=auth/munge
DbdHost=localhost
DbdAddr=127.0.0.1
DbdPort=$PORT_DBD
SlurmUser=root
PidFile=$d/run/slurmdbd.pid
LogFile=$d/log/slurmdbd.log
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$PORT_DB
StorageUser=slurm
StoragePass=enclab-test
StorageLoc=slurm_acct_db
CONF
    chmod 600 "$d/etc/slurmdbd.conf"
}

# start_daemon NAME COMMAND...: run a daemon in the foreground mode in the background and keep
# its pid in DIR/run/NAME.fg.pid for stop. setsid puts it in a session of its own, so that a
# Ctrl-C in the terminal reaches Snakemake (which then cancels its jobs through slurmctld) but not
# the daemons; stop ends them. (In a script without job control the background child is no
# group leader, so setsid does not fork and $! is the daemon itself.)
start_daemon() {
    local name=$1
    shift
    setsid "$@" </dev/null >>"$DIR/log/$name.out" 2>&1 &
    echo $! >"$DIR/run/$name.fg.pid"
}

start() {
    DIR=$(realpath -m "$1")
    [[ -e $DIR/run ]] && { log "$DIR is in use (stop it first)"; return 1; }
    write_configs "$DIR"
    export SLURM_CONF=$DIR/etc/slurm.conf

    # munged on its default socket: SLURM 22.05's clients (sacctmgr to slurmdbd) ignore
    # AuthInfo=socket=..., so a private socket would not reach every daemon.
    if [[ -S $MUNGE_SOCKET ]] && munge -n -S "$MUNGE_SOCKET" >/dev/null 2>&1; then
        log "a munged already answers on $MUNGE_SOCKET (a system munge?): stop it first"
        return 1
    fi
    log "munged"
    mkdir -p "$(dirname "$MUNGE_SOCKET")"
    start_daemon munged /usr/sbin/munged --foreground --force --key-file="$DIR/munge/munge.key" \
        --socket="$MUNGE_SOCKET" --pid-file="$DIR/run/munged.pid" \
        --log-file="$DIR/log/munged.log" --seed-file="$DIR/munge/munge.seed"
    wait_for 20 munged sh -c "munge -n -S '$MUNGE_SOCKET' | unmunge -S '$MUNGE_SOCKET'"

    log "MariaDB (accounting database)"
    mariadb-install-db --no-defaults --user=root --datadir="$DIR/db" \
        --auth-root-authentication-method=socket >"$DIR/log/mariadb-install.log" 2>&1
    start_daemon mariadbd /usr/sbin/mariadbd --no-defaults --user=root --datadir="$DIR/db" \
        --socket="$DIR/run/mysql.sock" --port=$PORT_DB --bind-address=127.0.0.1 \
        --skip-name-resolve --pid-file="$DIR/run/mariadbd.pid" --log-error="$DIR/log/mariadbd.log" \
        --innodb-buffer-pool-size=64M
    wait_for 60 MariaDB mariadb-admin --no-defaults --socket="$DIR/run/mysql.sock" ping
    mariadb --no-defaults --socket="$DIR/run/mysql.sock" -u root <<SQL
CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY 'enclab-test';
GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';
SQL

    log "slurmdbd"
    start_daemon slurmdbd /usr/sbin/slurmdbd -D
    wait_for 60 slurmdbd sacctmgr -n list cluster
    sacctmgr -i add cluster enclab >/dev/null
    sacctmgr -i add account enclab Cluster=enclab Description=test Organization=enclab >/dev/null
    sacctmgr -i add user root Account=enclab DefaultAccount=enclab >/dev/null

    log "slurmctld and slurmd (NodeName=localhost CPUs=$CPUS)"
    start_daemon slurmctld /usr/sbin/slurmctld -D -i
    wait_for 60 slurmctld scontrol ping
    start_daemon slurmd /usr/sbin/slurmd -D -N localhost --conf-server 127.0.0.1:$PORT_CTLD
    wait_for 120 "node localhost idle" sh -c "sinfo -h -n localhost -o %t | grep -qx idle"
    log "cluster up: $(sinfo -h -o '%P %D %t %c CPUs')  (SLURM_CONF=$SLURM_CONF)"
}

stop() {
    DIR=$(realpath -m "$1")
    [[ -d $DIR/run ]] || return 0
    export SLURM_CONF=$DIR/etc/slurm.conf
    # Jobs still queued or running (a failed or interrupted test) are cancelled first, so that no
    # job step outlives the cluster.
    local name pid jobs
    if jobs=$(squeue -h -o %i 2>/dev/null) && [[ -n $jobs ]]; then
        # shellcheck disable=SC2086
        scancel $jobs 2>/dev/null || true
        wait_for 30 "cancelled jobs to end" sh -c '[ -z "$(squeue -h -o %i)" ]' || true
    fi
    # Reverse order of start; each daemon gets TERM, then KILL if it lingers.
    for name in slurmd slurmctld slurmdbd mariadbd munged; do
        [[ -f $DIR/run/$name.fg.pid ]] || continue
        pid=$(cat "$DIR/run/$name.fg.pid")
        if kill -0 "$pid" 2>/dev/null; then
            kill -TERM "$pid" 2>/dev/null || true
            for _ in $(seq 1 40); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
            kill -KILL "$pid" 2>/dev/null || true
        fi
        rm -f "$DIR/run/$name.fg.pid"
    done
    # slurmd's configless cache: stale once the cluster is gone.
    rm -rf /run/slurm/conf
    log "cluster in $DIR stopped"
}

case ${1:-} in
    install) install ;;
    start) start "${2:?usage: $0 start DIR}" ;;
    stop) stop "${2:?usage: $0 stop DIR}" ;;
    *) echo "usage: $0 install | start DIR | stop DIR" >&2; exit 2 ;;
esac
