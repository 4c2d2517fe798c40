//! `railview verify DB`: checks every file of a database; exit status 0 only when intact.

use std::path::PathBuf;

use anyhow::Context;

#[derive(clap::Args)]
pub struct Args {
    /// Database directory (the one holding manifest.json and objects/).
    pub db: PathBuf,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let report = streamer::db::verify(&args.db)
        .with_context(|| format!("verifying {}", args.db.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{}: {} objects referenced, {} files ({} bytes) hashed, {} PTM level ranges checked",
            args.db.display(),
            report.objects_referenced,
            report.files_checked,
            report.bytes_checked,
            report.level_ranges_checked
        );
        for n in &report.notes {
            println!("note: {}: {}", n.path.display(), n.what);
        }
        for p in &report.problems {
            println!("DAMAGED: {}: {}", p.path.display(), p.what);
        }
    }
    if report.is_intact() {
        println!("intact");
        Ok(())
    } else {
        anyhow::bail!(
            "{} problem(s) in {}; first: {}: {}",
            report.problems.len(),
            args.db.display(),
            report.problems[0].path.display(),
            report.problems[0].what
        )
    }
}
