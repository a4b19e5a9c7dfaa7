//! `cargo xtask slurm-up` / `slurm-down`: a real one-node Slurm cluster on this machine for the
//! cluster tests: Debian's `slurm-wlm` and `munge` (installed when missing), slurmctld and
//! slurmd on localhost, configuration, state, spool and logs under `/tmp/timesift-slurm`.
//! Tests find it through `SLURM_CONF` or at [`CONF`].

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

/// Where the cluster lives.
const ROOT: &str = "/tmp/timesift-slurm";
/// Its slurm.conf (what `SLURM_CONF` must name).
pub const CONF: &str = "/tmp/timesift-slurm/slurm.conf";

fn found(program: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {program}")])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn run(program: &str, args: &[&str]) -> Result<()> {
    let status = Command::new(program)
        .args(args)
        .env("SLURM_CONF", CONF)
        .env("DEBIAN_FRONTEND", "noninteractive")
        .status()
        .with_context(|| format!("cannot run {program}"))?;
    if !status.success() {
        bail!("{program} {} failed ({status})", args.join(" "));
    }
    Ok(())
}

/// The configuration of a one-node cluster: this host's short name, its CPUs and most of its
/// memory; no accounting database (`sacct` then knows nothing, and `timesift status` says so).
fn slurm_conf(host: &str, cpus: usize, memory_mib: u64) -> String {
    format!(
        "ClusterName=timesift
SlurmctldHost={host}(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
StateSaveLocation={ROOT}/state
SlurmdSpoolDir={ROOT}/spool
SlurmctldPidFile={ROOT}/slurmctld.pid
SlurmdPidFile={ROOT}/slurmd.pid
SlurmctldLogFile={ROOT}/slurmctld.log
SlurmdLogFile={ROOT}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
KillWait=5
MinJobAge=300
NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} RealMemory={memory_mib} State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
"
    )
}

fn memory_mib() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(4096, |kib| kib / 1024 * 4 / 5)
}

/// Installs what is missing, writes the configuration and starts munged, slurmctld and slurmd;
/// returns when the node is idle.
pub fn up() -> Result<()> {
    if !(found("slurmctld") && found("slurmd") && found("munged") && found("sbatch")) {
        println!("installing slurm-wlm and munge (Debian packages)");
        let install = [
            "install",
            "-y",
            "-qq",
            "--no-install-recommends",
            "slurm-wlm",
            "munge",
        ];
        run("apt-get", &install)
            .or_else(|_| {
                run("apt-get", &["update", "-qq"])?;
                run("apt-get", &install)
            })
            .context("cannot install slurm-wlm and munge (root and Debian's packages needed)")?;
    }
    if Path::new(ROOT).join("slurmctld.pid").exists() && ping() {
        println!("Slurm is already up ({CONF})");
        return Ok(());
    }
    for dir in ["state", "spool"] {
        std::fs::create_dir_all(Path::new(ROOT).join(dir))?;
    }
    std::fs::create_dir_all("/run/munge")?;
    let host = String::from_utf8(Command::new("hostname").arg("-s").output()?.stdout)?
        .trim()
        .to_string();
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    std::fs::write(CONF, slurm_conf(&host, cpus, memory_mib()))?;
    if !Path::new("/etc/munge/munge.key").exists() {
        run("mungekey", &["--create"]).or_else(|_| run("create-munge-key", &[]))?;
    }
    // munged refuses root without --force; a running one is kept.
    let _ = Command::new("munged").arg("--force").status();
    run("slurmctld", &[])?;
    run("slurmd", &[])?;
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(60) {
        let out = Command::new("sinfo")
            .args(["-h", "-o", "%t"])
            .env("SLURM_CONF", CONF)
            .output()?;
        if String::from_utf8_lossy(&out.stdout).trim() == "idle" {
            println!("Slurm is up: one node ({cpus} CPUs); export SLURM_CONF={CONF}");
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    bail!("slurmd did not come up within 60 s: see {ROOT}/slurmd.log and slurmctld.log")
}

fn ping() -> bool {
    Command::new("scontrol")
        .arg("ping")
        .env("SLURM_CONF", CONF)
        .output()
        .is_ok_and(|o| o.status.success() && String::from_utf8_lossy(&o.stdout).contains("UP"))
}

/// Stops slurmd and slurmctld (their pid files) and removes the cluster's state.
pub fn down() -> Result<()> {
    for daemon in ["slurmd", "slurmctld"] {
        let pid_file = Path::new(ROOT).join(format!("{daemon}.pid"));
        if let Ok(pid) = std::fs::read_to_string(&pid_file) {
            let _ = Command::new("kill").arg(pid.trim()).status();
        }
    }
    std::thread::sleep(Duration::from_secs(1));
    let _ = std::fs::remove_dir_all(ROOT);
    println!("Slurm stopped; {ROOT} removed");
    Ok(())
}
