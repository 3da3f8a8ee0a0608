//! What a denoised frame did: the `--json` report of one set or a sequence, and the lines the
//! user reads after the work (notes, `--timings`, the summary), made from the same record.

use serde::Serialize;

use crate::condition::SanitizeReport;
use crate::filters::StageReport;
use crate::io;
use crate::pipeline::Pipeline;

/// What one `gsid denoise` frame did (`--json`; the human lines are made from it too).
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    /// The render set folder or file the frame was read from.
    pub input: String,
    pub inputs: Vec<InputJson>,
    pub width: usize,
    pub height: usize,
    /// What reading said: the channel mapping, missing buffers, LDR colour.
    pub input_notes: Vec<String>,
    /// What the pipeline said (brightness scaling, sanitised input, fallbacks).
    pub notes: Vec<String>,
    pub stages: Vec<StageReport>,
    pub walk_steps: u64,
    pub sanitized: SanitizeReport,
    pub seconds: Seconds,
    pub output: String,
    /// Buffers saved with `--save-buffer`.
    pub saved: Vec<SavedJson>,
}

/// One input buffer: the file it was read from and which channels (or layer) became it.
#[derive(Clone, Debug, Serialize)]
pub struct InputJson {
    pub buffer: String,
    pub file: String,
    pub source: String,
}

impl InputJson {
    /// The buffers of a loaded set, each with its source.
    pub fn list(set: &io::LoadedSet) -> Vec<InputJson> {
        set.files
            .iter()
            .map(|(buffer, file)| InputJson {
                buffer: buffer.clone(),
                file: file.display().to_string(),
                source: set
                    .sources
                    .iter()
                    .find(|(b, _)| b == buffer)
                    .map_or_else(|| file.display().to_string(), |(_, s)| s.clone()),
            })
            .collect()
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct SavedJson {
    pub buffer: String,
    pub file: String,
}

/// Wall time of a frame's parts, in seconds.
#[derive(Clone, Debug, Serialize)]
pub struct Seconds {
    pub read: f64,
    pub pipeline: f64,
    pub write: f64,
    pub total: f64,
}

/// The pipeline a run used: its name and its stages' ids, in order.
#[derive(Clone, Debug, Serialize)]
pub struct PipelineJson {
    pub name: String,
    pub stages: Vec<String>,
}

impl PipelineJson {
    pub fn of(pipeline: &Pipeline) -> Self {
        PipelineJson {
            name: pipeline.name.clone(),
            stages: pipeline.stages.iter().map(|s| s.id().to_string()).collect(),
        }
    }
}

/// `gsid denoise --json` of one render set.
#[derive(Serialize)]
pub struct SingleJson {
    /// The gsid that wrote the report (`CARGO_PKG_VERSION`).
    pub version: &'static str,
    pub pipeline: PipelineJson,
    pub seed: u64,
    #[serde(flatten)]
    pub outcome: Outcome,
}

/// `gsid denoise --json` of a sequence or a folder of render sets.
#[derive(Serialize)]
pub(super) struct SequenceJson {
    pub version: &'static str,
    pub pipeline: PipelineJson,
    pub seed: u64,
    pub frames: Vec<Entry>,
    pub done: usize,
    pub skipped: usize,
    pub failed: Vec<FrameId>,
}

/// A frame of a batch in JSON: a pattern's frame number as a number, a render set folder's name as
/// a string.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(untagged)]
pub(super) enum FrameId {
    Number(u64),
    Name(String),
}

impl FrameId {
    /// A pattern's frame by its number, else a render set by its name.
    pub fn of(number: Option<u64>, label: &str) -> Self {
        number.map_or_else(|| FrameId::Name(label.to_string()), FrameId::Number)
    }
}

impl std::fmt::Display for FrameId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FrameId::Number(n) => write!(f, "{n}"),
            FrameId::Name(name) => f.write_str(name),
        }
    }
}

#[derive(Serialize)]
pub(super) struct Entry {
    pub frame: FrameId,
    #[serde(flatten)]
    pub outcome: Outcome,
}

/// What became of one frame.
#[derive(Serialize)]
#[serde(tag = "status", rename_all = "lowercase")]
pub enum Outcome {
    Done(Box<FrameReport>),
    Skipped { output: String },
    Failed { error: String, exit_code: i32 },
}

/// What a denoised frame tells the user after the work: the run's notes, `--timings`, the summary.
pub(super) fn tell(report: &FrameReport, timings: bool, say: &dyn Fn(&str)) {
    for line in &report.notes {
        say(line);
    }
    let seconds = &report.seconds;
    if timings {
        say(&format!("  {:<12}         {:>8.4} s", "read", seconds.read));
        for st in &report.stages {
            say(&format!(
                "  {:<12} level {} {:>8.4} s {:>6.2} M walk steps",
                st.id,
                st.level,
                st.seconds,
                st.walk_steps as f64 / 1e6
            ));
        }
        say(&format!(
            "  {:<12}         {:>8.4} s",
            "write", seconds.write
        ));
    }
    say(&format!(
        "{} ({}x{}) → {} in {:.3} s (pipeline {:.3} s, {:.1} M walk steps)",
        report.input,
        report.width,
        report.height,
        report.output,
        seconds.total,
        seconds.pipeline,
        report.walk_steps as f64 / 1e6
    ));
}
