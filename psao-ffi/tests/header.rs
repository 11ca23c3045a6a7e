//! include/psao.h is what cbindgen makes of this crate: regenerated here
//! and compared with the committed copy, so the header never drifts from
//! the code. `PSAO_BLESS=1 cargo test -p psao-ffi --test header` rewrites
//! it after an API change.

use std::path::PathBuf;

#[test]
fn committed_header_matches_the_code() {
    let crate_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let config =
        cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_crate(&crate_dir)
        .with_config(config)
        .generate()
        .expect("cbindgen parses psao-ffi")
        .write(&mut generated);
    let path = crate_dir.join("../include/psao.h");
    if std::env::var_os("PSAO_BLESS").is_some() {
        std::fs::write(&path, &generated).unwrap();
        return;
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "include/psao.h differs from what cbindgen generates from psao-ffi: \
         run `PSAO_BLESS=1 cargo test -p psao-ffi --test header` and commit it"
    );
}
