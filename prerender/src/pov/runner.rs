//! Running the `povray` process: command line, timeout, log, statistics and error text.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use super::PovError;

/// Output file type of a render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OutputFormat {
    /// 8-bit sRGB PNG (colour).
    Png8,
    /// 16-bit PNG written with `File_Gamma` (fog-trick depth).
    Png16 { file_gamma: f64 },
}

/// One POV-Ray invocation.
#[derive(Clone, Debug)]
pub struct RenderJob {
    /// Human-readable name for progress and errors (`sample 3 depth`).
    pub name: String,
    pub wrapper: PathBuf,
    pub output: PathBuf,
    pub log: PathBuf,
    pub width: u32,
    pub height: u32,
    pub format: OutputFormat,
    /// Render block size (`+BS`); see the dummy-row note in `frame`.
    pub block_size: u32,
    /// Extra include directories (`+L`), e.g. the scene's own directory.
    pub library_dirs: Vec<PathBuf>,
    /// `Declare=NAME=VALUE` pairs.
    pub declares: Vec<(&'static str, f64)>,
    /// Further options, after every other one (so they win): e.g. a radiosity file.
    pub extra: Vec<String>,
}

/// POV-Ray's own timings for one render, from its statistics stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RenderStats {
    pub wall_seconds: f64,
    pub parse_seconds: f64,
    pub bounding_seconds: f64,
    pub photon_seconds: f64,
    pub radiosity_seconds: f64,
    pub trace_seconds: f64,
}

impl RenderStats {
    pub fn add(&mut self, o: &RenderStats) {
        self.wall_seconds += o.wall_seconds;
        self.parse_seconds += o.parse_seconds;
        self.bounding_seconds += o.bounding_seconds;
        self.photon_seconds += o.photon_seconds;
        self.radiosity_seconds += o.radiosity_seconds;
        self.trace_seconds += o.trace_seconds;
    }
}

/// How to run POV-Ray.
#[derive(Clone, Debug)]
pub struct PovRay {
    pub binary: PathBuf,
    pub threads: usize,
    pub timeout: Option<Duration>,
}

impl PovRay {
    /// Check that the binary runs at all, returning its version line.
    pub fn version(&self) -> Result<String, PovError> {
        let out = Command::new(&self.binary)
            .arg("--version")
            .stdin(Stdio::null())
            .output()
            .map_err(|source| PovError::PovrayMissing {
                binary: self.binary.clone(),
                source,
            })?;
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        text.lines()
            .find(|l| l.contains("POV-Ray 3.") || l.starts_with("POV-Ray"))
            .map(|l| l.trim().to_string())
            .ok_or_else(|| PovError::PovrayMissing {
                binary: self.binary.clone(),
                source: std::io::Error::other(format!(
                    "`{} --version` did not report a POV-Ray version: {}",
                    self.binary.display(),
                    text.trim()
                )),
            })
    }

    /// The command-line arguments of a job.
    pub fn args(&self, job: &RenderJob) -> Vec<String> {
        let mut a = vec![
            format!("+I{}", job.wrapper.display()),
            format!("+O{}", job.output.display()),
            format!("+W{}", job.width),
            format!("+H{}", job.height),
            "-D".into(),
            "-V".into(),
            "-P".into(),
            "-A".into(),
            format!("+WT{}", self.threads.max(1)),
            "+Q9".into(),
            "+MV3.7".into(),
            format!("+BS{}", job.block_size.max(1)),
        ];
        match job.format {
            OutputFormat::Png8 => a.push("+FN8".into()),
            OutputFormat::Png16 { file_gamma } => {
                a.push("+FN16".into());
                a.push(format!("File_Gamma={file_gamma}"));
            }
        }
        for dir in &job.library_dirs {
            a.push(format!("+L{}", dir.display()));
        }
        for (name, value) in &job.declares {
            a.push(format!("Declare={name}={value}"));
        }
        a.extend(job.extra.iter().cloned());
        a
    }

    /// Run a job to completion (or its timeout). The log (stdout and stderr) is kept at
    /// `job.log`; on failure the error carries POV-Ray's own message with file and line.
    pub fn run(&self, job: &RenderJob) -> Result<RenderStats, PovError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| PovError::Io { path, source }
        };
        if let Some(dir) = job.log.parent() {
            fs::create_dir_all(dir).map_err(io(dir))?;
        }
        let log = fs::File::create(&job.log).map_err(io(&job.log))?;
        let log2 = log.try_clone().map_err(io(&job.log))?;
        // A stale output from an earlier, killed run must not be mistaken for this one's.
        if job.output.exists() {
            fs::remove_file(&job.output).map_err(io(&job.output))?;
        }
        let start = Instant::now();
        let mut child = Command::new(&self.binary)
            .args(self.args(job))
            .stdin(Stdio::null())
            .stdout(log)
            .stderr(log2)
            .spawn()
            .map_err(|source| PovError::PovrayMissing {
                binary: self.binary.clone(),
                source,
            })?;
        let status = loop {
            if let Some(status) = child.try_wait().map_err(io(&self.binary))? {
                break status;
            }
            if let Some(limit) = self.timeout {
                if start.elapsed() > limit {
                    // Killing may race with a normal exit; either way we wait and report.
                    child.kill().ok();
                    child.wait().ok();
                    return Err(PovError::Timeout {
                        render: job.name.clone(),
                        seconds: limit.as_secs_f64(),
                        log: job.log.clone(),
                    });
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let wall = start.elapsed().as_secs_f64();
        let text = fs::read_to_string(&job.log).unwrap_or_default();
        if !status.success() || !job.output.exists() {
            return Err(PovError::Render {
                render: job.name.clone(),
                status: status.to_string(),
                message: error_text(&text),
                log: job.log.clone(),
            });
        }
        let mut stats = parse_stats(&text);
        stats.wall_seconds = wall;
        Ok(stats)
    }
}

/// The seconds in brackets on the line of `label`, e.g.
/// `Parse Time:       0 hours  0 minutes  0 seconds (0.012 seconds)`.
fn seconds_after(text: &str, label: &str) -> f64 {
    text.lines()
        .filter(|l| l.trim_start().starts_with(label))
        .filter_map(|l| {
            let open = l.rfind('(')?;
            let inner = &l[open + 1..];
            inner.split_whitespace().next()?.parse::<f64>().ok()
        })
        .fold(0.0, |a, b| a + b)
}

/// POV-Ray's statistics (wall time left 0).
pub fn parse_stats(log: &str) -> RenderStats {
    RenderStats {
        wall_seconds: 0.0,
        parse_seconds: seconds_after(log, "Parse Time:"),
        bounding_seconds: seconds_after(log, "Bounding Time:"),
        photon_seconds: seconds_after(log, "Photon Time:"),
        radiosity_seconds: seconds_after(log, "Radiosity Time:"),
        trace_seconds: seconds_after(log, "Trace Time:"),
    }
}

/// The error part of a POV-Ray log: lines naming an error (with their indented continuation
/// lines), `File 'x' line N:` rewritten as `x:N:`. Falls back to the log's last lines.
pub fn error_text(log: &str) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut keep = false;
    for line in log.lines() {
        if line.starts_with(' ') && keep {
            if let Some(last) = out.last_mut() {
                last.push_str(line);
            }
            continue;
        }
        let lower = line.to_ascii_lowercase();
        keep = lower.contains("error")
            || lower.contains("cannot")
            || lower.contains("failed")
            || lower.contains("not found");
        if keep && !line.trim().is_empty() {
            out.push(relocate(line));
        }
    }
    if out.is_empty() {
        let lines: Vec<&str> = log.lines().collect();
        let from = lines.len().saturating_sub(8);
        return lines[from..].join("\n");
    }
    out.join("\n")
}

/// `File 'scene.pov' line 12: Parse Error: …` → `scene.pov:12: Parse Error: …`.
fn relocate(line: &str) -> String {
    let parsed = (|| {
        let rest = line.strip_prefix("File '")?;
        let (file, rest) = rest.split_once("' line ")?;
        let (num, msg) = rest.split_once(':')?;
        let num: u64 = num.trim().parse().ok()?;
        Some(format!("{file}:{num}:{msg}"))
    })();
    parsed.unwrap_or_else(|| line.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOG: &str = r"==== [Parsing...] ===
File 'bad.pov' line 3: Possible Parse Error: Cannot find file 'nope.inc', even
 after trying to append file type extension.
File 'bad.pov' line 3: Parse Error: Cannot open include file nope.inc.
Fatal error in parser: Cannot parse input.
Render failed
";

    #[test]
    fn error_text_names_file_and_line() {
        let e = error_text(LOG);
        assert!(
            e.contains("bad.pov:3: Parse Error: Cannot open include file nope.inc."),
            "{e}"
        );
        assert!(e.contains("even after trying"), "continuation joined: {e}");
        assert!(!e.contains("Parsing..."));
    }

    #[test]
    fn stats_are_parsed() {
        let log = "  Parse Time:       0 hours  0 minutes  1 seconds (1.250 seconds)\n\
                   using 1 thread(s)\n\
                   Radiosity Time:   No radiosity\n\
                   Trace Time:       0 hours  0 minutes  0 seconds (0.031 seconds)\n";
        let s = parse_stats(log);
        assert_eq!(s.parse_seconds, 1.25);
        assert_eq!(s.trace_seconds, 0.031);
        assert_eq!(s.radiosity_seconds, 0.0);
    }
}
