//! Builds Intel's Masked Occlusion Culling, the peer the occlusion stage is measured against, from
//! `../shared/peers/moc` (or `CULLET_MOC_DIR`), with a small C shim of this package. MOC's sources stay outside
//! the project's tree. Where they are absent, or on a target MOC does not support (it needs x86-64), the peer
//! is left out: the benches then say why (`CULLET_MOC_MISSING`) instead of measuring it.

use std::path::PathBuf;

fn main() {
    println!("cargo::rustc-check-cfg=cfg(moc)");
    println!("cargo::rerun-if-env-changed=CULLET_MOC_DIR");
    println!("cargo::rerun-if-changed=moc/shim.cpp");
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let source = std::env::var_os("CULLET_MOC_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| manifest.join("../../shared/peers/moc"));
    let missing = if std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() != Ok("x86_64") {
        Some("Intel MOC needs an x86-64 target".to_string())
    } else if !source.join("MaskedOcclusionCulling.h").exists() {
        Some(format!("Intel MOC's sources are not in {} (set CULLET_MOC_DIR)", source.display()))
    } else {
        None
    };
    if let Some(why) = missing {
        println!("cargo::warning=the Intel MOC peer is left out of the benches: {why}");
        println!("cargo::rustc-env=CULLET_MOC_MISSING={why}");
        return;
    }
    println!("cargo::rerun-if-changed={}", source.display());
    println!("cargo::rustc-cfg=moc");

    // The per-file instruction sets of MOC's own build script: the dispatcher and the thread pool must run on
    // any x86-64, each SIMD back end gets its own.
    let isa = ["-mbmi", "-mbmi2", "-mlzcnt", "-mpopcnt", "-mfma"];
    let library = |name: &str, files: &[&str], flags: &[&str], shim: bool| {
        let mut build = cc::Build::new();
        build.cpp(true).std("c++14").opt_level(2).warnings(false).include(&source);
        for flag in flags {
            build.flag(flag);
        }
        for file in files {
            build.file(if shim { manifest.join(file) } else { source.join(file) });
        }
        build.compile(name);
    };
    // Static libraries are linked in this order: the shim, then what it calls, then the SIMD back ends.
    library("cullet_moc_shim", &["moc/shim.cpp"], &["-msse4.1"], true);
    library("moc_dispatch", &["MaskedOcclusionCulling.cpp", "CullingThreadpool.cpp"], &["-msse4.1"], false);
    library("moc_avx2", &["MaskedOcclusionCullingAVX2.cpp"], &[&["-mavx2"][..], &isa].concat(), false);
    let avx512 = [&["-mavx512f", "-mavx512bw", "-mavx512dq", "-mavx2"][..], &isa].concat();
    library("moc_avx512", &["MaskedOcclusionCullingAVX512.cpp"], &avx512, false);
}
