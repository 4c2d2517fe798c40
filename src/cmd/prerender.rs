//! `railview prerender`.

/// Arguments of `railview prerender`.
#[derive(clap::Args)]
pub struct Args {
    /// Built-in scene name (`castle`, `nature`) or a scene TOML file.
    #[arg(long)]
    pub scene: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::bail!(
        "prerender of `{}`: the ray tracer is not built yet",
        args.scene
    )
}
