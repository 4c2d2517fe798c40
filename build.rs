//! Test switches: `RAILVIEW_SKIP_SLURM_TESTS=1`, `RAILVIEW_SKIP_NAMESPACE_TESTS=1`,
//! `RAILVIEW_SKIP_NGINX_TESTS=1`, `RAILVIEW_SKIP_GPU_TESTS=1`, `RAILVIEW_SKIP_BROWSER=1` and
//! `RAILVIEW_SKIP_NODE_TESTS=1` mark the tests that need a Slurm cluster, PID namespaces,
//! nginx, a GPU adapter, Chromium or Node.js (root and packages that `scripts/test.sh` installs) as ignored, with the reason,
//! instead of failing them. Nothing else is built here.

fn main() {
    for (var, cfg) in [
        ("RAILVIEW_SKIP_SLURM_TESTS", "railview_skip_slurm"),
        ("RAILVIEW_SKIP_NAMESPACE_TESTS", "railview_skip_namespaces"),
        ("RAILVIEW_SKIP_GPU_TESTS", "railview_skip_gpu"),
        ("RAILVIEW_SKIP_BROWSER", "railview_skip_browser"),
        ("RAILVIEW_SKIP_NGINX_TESTS", "railview_skip_nginx"),
        ("RAILVIEW_SKIP_NODE_TESTS", "railview_skip_node"),
    ] {
        println!("cargo::rustc-check-cfg=cfg({cfg})");
        println!("cargo::rerun-if-env-changed={var}");
        if std::env::var(var).is_ok_and(|v| v == "1") {
            println!("cargo::rustc-cfg={cfg}");
        }
    }
}
