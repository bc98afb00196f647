//! Measurements: printed as they come, collected for the JSON file.

use kinetrace::gpu::GpuContext;
use serde_json::{Value, json};
use std::time::Instant;

/// One measured value.
pub struct Record {
    pub suite: &'static str,
    pub scene: String,
    pub subject: String,
    pub metric: &'static str,
    pub value: f64,
    pub unit: &'static str,
}

/// All measurements of a run, plus the run's settings and the GPU its suites share.
pub struct Records {
    pub quick: bool,
    pub threads: usize,
    rows: Vec<Record>,
    /// Created by the first suite that asks; the reason as text where there is no adapter.
    gpu: Option<Result<GpuContext, String>>,
}

impl Records {
    pub fn new(quick: bool) -> Self {
        Self {
            quick,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            rows: Vec::new(),
            gpu: None,
        }
    }

    /// Records and prints one value.
    pub fn add(
        &mut self,
        suite: &'static str,
        scene: &str,
        subject: &str,
        metric: &'static str,
        value: f64,
        unit: &'static str,
    ) {
        println!("  {subject:<34} {metric:<22} {value:>12.3} {unit}");
        self.rows.push(Record {
            suite,
            scene: scene.to_string(),
            subject: subject.to_string(),
            metric,
            value,
            unit,
        });
    }

    /// The GPU every suite of the run measures on, created on the first call (device creation and shader
    /// compilation cost tens to hundreds of milliseconds, paid once); `Err` with the reason where there is
    /// none. Its adapter goes to the JSON.
    pub fn gpu(&mut self) -> Result<GpuContext, String> {
        self.gpu
            .get_or_insert_with(|| GpuContext::new().map_err(|e| e.to_string()))
            .clone()
    }

    /// Repetitions of each timed step.
    pub fn reps(&self) -> usize {
        if self.quick { 2 } else { 5 }
    }

    /// The run as a JSON document: the machine, the GPU adapter (`null` when no suite used one, with
    /// `gpu_error` saying why when there was none), the settings, and every record. Non-finite values
    /// are written as `null`.
    pub fn to_json(&self) -> String {
        let (adapter, details, error) = match &self.gpu {
            Some(Ok(c)) => (
                json!(c.adapter_name()),
                json!(c.adapter_details()),
                Value::Null,
            ),
            Some(Err(e)) => (Value::Null, Value::Null, json!(e)),
            None => (Value::Null, Value::Null, Value::Null),
        };
        let records: Vec<Value> = self
            .rows
            .iter()
            .map(|r| {
                json!({
                    "suite": r.suite,
                    "scene": r.scene,
                    "subject": r.subject,
                    "metric": r.metric,
                    "value": r.value,
                    "unit": r.unit,
                })
            })
            .collect();
        let doc = json!({
            "machine": machine(),
            "gpu_adapter": adapter,
            "gpu_details": details,
            "gpu_error": error,
            "quick": self.quick,
            "threads": self.threads,
            "records": records,
        });
        format!("{doc:#}\n")
    }
}

/// CPU model and core count, for the record.
pub fn machine() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{model}, {threads} threads")
}

/// Seconds of the fastest of `reps` runs of `f`, and the last result.
pub fn best_of<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        let r = std::hint::black_box(f());
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.expect("at least one run"))
}

/// Which CPU clock [`cpu_seconds`] reads.
#[derive(Clone, Copy)]
pub enum CpuClock {
    /// All the process's threads together: what a parallel pass costs on a loaded machine, where
    /// wall-clock times depend on what else runs.
    Process,
    /// The calling thread's alone.
    Thread,
}

/// CPU time in seconds on `clock`. Wall time where no CPU clock is wired.
#[cfg(target_os = "linux")]
pub fn cpu_seconds(clock: CpuClock) -> f64 {
    #[repr(C)]
    struct Timespec {
        sec: i64,
        nsec: i64,
    }
    unsafe extern "C" {
        fn clock_gettime(clock: i32, tp: *mut Timespec) -> i32;
    }
    // Linux's CLOCK_PROCESS_CPUTIME_ID and CLOCK_THREAD_CPUTIME_ID.
    let id = match clock {
        CpuClock::Process => 2,
        CpuClock::Thread => 3,
    };
    let mut t = Timespec { sec: 0, nsec: 0 };
    // SAFETY: `t` is a writable timespec (two 64-bit fields on 64-bit Linux) and the clock id is Linux's.
    let ok = unsafe { clock_gettime(id, &mut t) } == 0;
    assert!(ok, "the CPU clock");
    t.sec as f64 + t.nsec as f64 * 1e-9
}

/// Wall time where no CPU clock is wired.
#[cfg(not(target_os = "linux"))]
pub fn cpu_seconds(_clock: CpuClock) -> f64 {
    use std::sync::OnceLock;
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64()
}
