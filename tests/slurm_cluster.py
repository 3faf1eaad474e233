"""A throw-away one-node SLURM cluster on this machine, for tests/test_slurm.py.

Debian's ``slurm-wlm`` and ``munge`` (installed with apt-get when missing), started as
root: a private ``munged`` (own key and socket), ``slurmctld`` and ``slurmd`` on
localhost, no accounting daemon. Everything they write (state, spool, logs, pid files,
the munge key) lives under one temporary folder; the only file written outside it is
``/etc/slurm/slurm.conf``, the path every Slurm command reads by default. It has to be
there: snakemake-executor-plugin-slurm-jobstep strips every ``SLURM_*`` variable,
``SLURM_CONF`` included, from the environment of the ``srun`` it runs inside each job,
so a configuration named only by ``SLURM_CONF`` is not found by that ``srun``. The file is
written only where none exists (or a stale one of ours), and removed by ``stop()``.

Settings that matter for Snakemake (see the README's cluster section):

* ``AccountingStorageType=accounting_storage/none``: ``sacct`` has nothing to read, so
  Snakemake must poll with ``--slurm-status-command squeue``;
* ``MinJobAge=300``: squeue still lists a finished job for 5 minutes, long enough for
  the plugin (which falls back to sacct below 3x its first polling interval) to see it;
* one partition, named as the profile's ``slurm_partition``;
* ``SlurmdParameters=config_overrides`` with the machine's CPU count and
  ``SelectTypeParameters=CR_Core``: CPUs are the consumable resource (as many jobs at
  once as ``--cores`` would run locally); memory is not consumed, and ``RealMemory`` is
  set to at least 16000 MB so that the profile's ``--mem`` requests are admitted even on
  a small CI machine (nothing enforces memory here).
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

#: Commands the cluster needs; apt-get installs them when one is missing.
TOOLS = ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "sinfo", "scancel", "srun")
PACKAGES = ("slurm-wlm", "munge")
SLURM_CONF = Path("/etc/slurm/slurm.conf")
#: First line of the slurm.conf we write; a file without it is never touched.
MARKER = "# Written by cvsim6 tests/slurm_cluster.py for a test cluster; removed when the test ends."


class Unavailable(Exception):
    """The cluster cannot run on this machine at all (the test skips with this reason, or fails
    with it under ``CVSIM6_REQUIRE_LOCAL=1``)."""


def ensure_installed(timeout: float = 900) -> None:
    """Install Debian's slurm-wlm and munge with apt-get if a needed command is missing.

    Raises :class:`Unavailable` when not root or when apt-get is missing; an apt-get that
    fails is an error (the test fails with its output).
    """
    if os.geteuid() != 0:
        raise Unavailable("a test SLURM cluster needs root (daemons, apt-get, /etc/slurm/slurm.conf)")
    if all(shutil.which(t) for t in TOOLS):
        return
    if not shutil.which("apt-get"):
        missing = [t for t in TOOLS if not shutil.which(t)]
        raise Unavailable(f"SLURM commands {missing} missing and apt-get not available to install them")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update", "-q"],
                ["apt-get", "install", "-y", "-q", "--no-install-recommends", *PACKAGES]):
        proc = subprocess.run(cmd, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              timeout=timeout)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    missing = [t for t in TOOLS if not shutil.which(t)]
    if missing:
        raise RuntimeError(f"installed {PACKAGES} but still missing {missing}")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _mem_total_mb() -> int:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return int(line.split()[1]) // 1024
    return 0


class Cluster:
    """One controller and one compute node on localhost; ``start()``, then ``stop()`` always."""

    def __init__(self, root: Path, partition: str = "standard", cpus: int | None = None):
        self.root = Path(root)
        self.partition = partition
        self.cpus = cpus or os.cpu_count() or 1
        self.node = socket.gethostname().split(".")[0]
        self.procs: dict[str, subprocess.Popen] = {}
        self.wrote_conf = False
        self.munge_socket = self.root / "munge" / "munge.socket"
        self.ctld_log = self.root / "log" / "slurmctld.log"
        self.slurmd_log = self.root / "log" / "slurmd.log"

    # ------------------------------------------------------------------ commands
    def run(self, *args: str, check: bool = True, timeout: float = 30) -> subprocess.CompletedProcess:
        """A Slurm client command against this cluster."""
        proc = subprocess.run(list(args), capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL)
        if check and proc.returncode != 0:
            raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}): {proc.stdout}{proc.stderr}")
        return proc

    def jobs(self) -> dict[str, tuple[str, str]]:
        """Every job slurmctld still knows (finished ones for MinJobAge): id -> (name, state)."""
        out = self.run("squeue", "--states=all", "--noheader", "--format=%i|%j|%T").stdout
        rows = [line.split("|") for line in out.splitlines() if line.strip()]
        return {r[0]: (r[1], r[2]) for r in rows}

    # ------------------------------------------------------------------ lifecycle
    def _config(self) -> str:
        r = self.root
        ctld_port, slurmd_port = _free_port(), _free_port()
        while slurmd_port == ctld_port:
            slurmd_port = _free_port()
        mem = max(_mem_total_mb(), 16000)
        return f"""{MARKER}
# Cluster of test run {r}
ClusterName=cvsim6test
SlurmctldHost={self.node}(127.0.0.1)
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
AuthType=auth/munge
AuthInfo=socket={self.munge_socket}
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation={r}/state
SlurmdSpoolDir={r}/spool
SlurmctldPidFile={r}/run/slurmctld.pid
SlurmdPidFile={r}/run/slurmd.pid
SlurmctldLogFile={self.ctld_log}
SlurmdLogFile={self.slurmd_log}
SlurmctldDebug=info
SlurmdDebug=info
MailProg=/bin/true
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MinJobAge=300
ReturnToService=2
SlurmdParameters=config_overrides
NodeName={self.node} NodeAddr=127.0.0.1 CPUs={self.cpus} RealMemory={mem} State=UNKNOWN
PartitionName={self.partition} Nodes=ALL Default=YES MaxTime=INFINITE State=UP
"""

    def _spawn(self, name: str, *cmd: str) -> None:
        out = open(self.root / "log" / f"{name}.out", "w")
        self.procs[name] = subprocess.Popen(list(cmd), stdout=out, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, start_new_session=True)
        out.close()

    def _wait(self, what: str, ready, timeout: float = 60) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for name, p in self.procs.items():
                if p.poll() is not None:
                    raise RuntimeError(f"{name} exited ({p.returncode}) while waiting for {what}:\n{self.logs()}")
            if ready():
                return
            time.sleep(0.5)
        raise RuntimeError(f"timed out after {timeout} s waiting for {what}:\n{self.logs()}")

    def logs(self, tail: int = 3000) -> str:
        parts = []
        for f in sorted((self.root / "log").glob("*")):
            parts.append(f"--- {f.name}\n{f.read_text(errors='replace')[-tail:]}")
        return "\n".join(parts)

    def start(self) -> None:
        for d in ("munge", "state", "spool", "run", "log"):
            (self.root / d).mkdir(parents=True, exist_ok=True)
        os.chmod(self.root / "munge", 0o755)  # clients reach the socket through it
        keydir = self.root / "munge-key"
        keydir.mkdir(mode=0o700, exist_ok=True)
        key = keydir / "munge.key"
        key.write_bytes(os.urandom(1024))
        os.chmod(key, 0o400)
        self._spawn("munged", "munged", "--foreground", "--force", f"--socket={self.munge_socket}",
                    f"--key-file={key}", f"--log-file={self.root / 'log' / 'munged.log'}",
                    f"--pid-file={self.root / 'run' / 'munged.pid'}", f"--seed-file={keydir / 'munged.seed'}")
        self._wait("munged's socket", self.munge_socket.exists, 30)

        if SLURM_CONF.exists() and not SLURM_CONF.read_text(errors="replace").startswith(MARKER):
            raise Unavailable(f"{SLURM_CONF} exists (a real cluster's configuration?); not overwriting it")
        SLURM_CONF.parent.mkdir(parents=True, exist_ok=True)
        SLURM_CONF.write_text(self._config())
        self.wrote_conf = True

        self._spawn("slurmctld", "slurmctld", "-D", "-c")
        self._wait("slurmctld", lambda: self.run("scontrol", "ping", check=False).returncode == 0)
        self._spawn("slurmd", "slurmd", "-D")

        def node_idle():
            p = self.run("sinfo", "--noheader", "--Node", "--format=%T", check=False)
            return p.returncode == 0 and p.stdout.strip() == "idle"

        self._wait("the node to become idle", node_idle)

    def stop(self) -> None:
        """Cancel every job, stop the daemons we started, remove our slurm.conf. Idempotent."""
        if "slurmctld" in self.procs and self.procs["slurmctld"].poll() is None:
            self.run("scancel", "--full", "--user=root", check=False)
            end = time.monotonic() + 30
            while time.monotonic() < end:
                p = self.run("squeue", "--noheader", "--states=RUNNING,PENDING,COMPLETING,CONFIGURING",
                             "--format=%i", check=False)
                if p.returncode != 0 or not p.stdout.strip():
                    break
                time.sleep(0.5)
        for name in ("slurmd", "slurmctld", "munged"):  # node first, munge last
            p = self.procs.get(name)
            if p is None or p.poll() is not None:
                continue
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
        if self.wrote_conf and SLURM_CONF.exists() and SLURM_CONF.read_text(errors="replace").startswith(MARKER):
            SLURM_CONF.unlink()
        self.wrote_conf = False
