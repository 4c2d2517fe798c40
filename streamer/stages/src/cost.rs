//! CPU time: what a stage of a build costs, whatever the number of cores it ran on.

/// CPU seconds used so far by this process (all its threads) and by the child processes it
/// has waited for (POV-Ray renders), user plus system; `None` where the operating system does
/// not say (only Linux's `/proc/self/stat` is read).
pub fn cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/self/stat").ok()?;
    parse_stat(&text)
}

/// Clock ticks per second of `/proc` times: `sysconf(_SC_CLK_TCK)`, which is 100 on every
/// Linux architecture's user-space ABI.
const TICKS_PER_SECOND: f64 = 100.0;

/// utime + stime + cutime + cstime of a `/proc/PID/stat` line, in seconds.
fn parse_stat(text: &str) -> Option<f64> {
    // The command name (field 2) is in parentheses and may hold spaces: split after it.
    let rest = &text[text.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // `rest` starts at field 3 (state); utime is field 14, so index 11.
    let ticks: f64 = fields
        .get(11..15)?
        .iter()
        .map(|f| f.parse::<f64>().ok())
        .sum::<Option<f64>>()?;
    Some(ticks / TICKS_PER_SECOND)
}

/// Measures the CPU seconds and wall seconds of what runs between [`Meter::start`] and
/// [`Meter::stop`].
#[derive(Clone, Copy, Debug)]
pub struct Meter {
    cpu: Option<f64>,
    wall: std::time::Instant,
}

impl Meter {
    pub fn start() -> Meter {
        Meter {
            cpu: cpu_seconds(),
            wall: std::time::Instant::now(),
        }
    }
    /// `(cpu_seconds, wall_seconds)`; CPU is NaN where it cannot be read.
    pub fn stop(&self) -> (f64, f64) {
        let cpu = match (self.cpu, cpu_seconds()) {
            (Some(a), Some(b)) => (b - a).max(0.0),
            _ => f64::NAN,
        };
        (cpu, self.wall.elapsed().as_secs_f64())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_fields_are_read_after_the_command_name() {
        let line = "1234 (rail view) R 1 2 3 4 5 6 7 8 9 10 150 50 20 30 20 0 1 0 99";
        assert_eq!(parse_stat(line), Some(2.5));
        assert_eq!(parse_stat("garbage"), None);
    }

    #[test]
    fn work_is_counted() {
        let m = Meter::start();
        // A fixed amount of work (not a fixed time: the machine may be shared), well above
        // the 10 ms resolution of the counters.
        let mut x = 0u64;
        for i in 0..100_000_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
        std::hint::black_box(x);
        let (cpu, wall) = m.stop();
        if cpu.is_finite() {
            assert!(cpu >= 0.02, "{cpu} s of CPU in {wall} s");
        }
    }
}
