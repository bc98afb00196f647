//! Measurements: printed as they come, collected for the JSON file.

use std::fmt::Write;
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

/// All measurements of a run, plus the run's settings.
pub struct Records {
    pub quick: bool,
    pub threads: usize,
    rows: Vec<Record>,
    notes: Vec<(String, String)>,
}

impl Records {
    pub fn new(quick: bool) -> Self {
        Self {
            quick,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            rows: Vec::new(),
            notes: Vec::new(),
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

    /// A fact about the run (e.g. the GPU adapter), written to the JSON.
    pub fn note(&mut self, key: &str, value: &str) {
        self.notes.push((key.to_string(), value.to_string()));
    }

    /// Repetitions of each timed step.
    pub fn reps(&self) -> usize {
        if self.quick { 2 } else { 5 }
    }

    pub fn to_json(&self) -> String {
        let mut s = String::new();
        let esc = |t: &str| t.replace('\\', "\\\\").replace('"', "\\\"");
        let _ = write!(
            s,
            "{{\n  \"quick\": {},\n  \"threads\": {},\n  \"machine\": \"{}\",\n  \"records\": [",
            self.quick,
            self.threads,
            esc(&machine())
        );
        for (k, v) in &self.notes {
            let _ = write!(s, "\n  \"{}\": \"{}\",", esc(k), esc(v));
        }
        for (i, r) in self.rows.iter().enumerate() {
            let v = if r.value.is_finite() {
                format!("{}", r.value)
            } else {
                "null".into()
            };
            let _ = write!(
                s,
                "{}\n    {{\"suite\": \"{}\", \"scene\": \"{}\", \"subject\": \"{}\", \"metric\": \"{}\", \"value\": {v}, \"unit\": \"{}\"}}",
                if i == 0 { "" } else { "," },
                r.suite,
                esc(&r.scene),
                esc(&r.subject),
                r.metric,
                r.unit
            );
        }
        s.push_str("\n  ]\n}\n");
        s
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
