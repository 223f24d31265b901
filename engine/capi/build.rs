//! Writes the C header from the crate's `extern "C"` items (cbindgen)
//! into OUT_DIR; the test `header_is_current` fails when the checked-in
//! `include/latentam.h` differs, and `LATENTAM_WRITE_HEADER=1 cargo build
//! -p latentam-capi` updates it.

fn main() {
    let crate_dir = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets it");
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets it"));
    println!("cargo:rerun-if-changed=src");
    println!("cargo:rerun-if-changed=cbindgen.toml");
    println!("cargo:rerun-if-env-changed=LATENTAM_WRITE_HEADER");
    let config = cbindgen::Config::from_file(format!("{crate_dir}/cbindgen.toml"))
        .expect("engine/capi/cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_crate(&crate_dir)
        .with_config(config)
        .generate()
        .expect("the C API's items translate to C");
    bindings.write_to_file(out.join("latentam.h"));
    if std::env::var_os("LATENTAM_WRITE_HEADER").is_some() {
        bindings.write_to_file(format!("{crate_dir}/include/latentam.h"));
    }
}
