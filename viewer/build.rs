//! Test switch: `RAILVIEW_SKIP_GPU_TESTS=1` marks the tests that need a GPU adapter (Mesa's
//! lavapipe or llvmpipe on machines without a GPU) as ignored, with the reason, instead of
//! failing them. Nothing else is built here.

fn main() {
    println!("cargo::rustc-check-cfg=cfg(railview_skip_gpu)");
    println!("cargo::rerun-if-env-changed=RAILVIEW_SKIP_GPU_TESTS");
    if std::env::var("RAILVIEW_SKIP_GPU_TESTS").is_ok_and(|v| v == "1") {
        println!("cargo::rustc-cfg=railview_skip_gpu");
    }
}
