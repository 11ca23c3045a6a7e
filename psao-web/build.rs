//! Embeds every file of `page/` (the browser client) in the library, so a
//! `psao` binary serves its page from anywhere.

use std::fmt::Write;
use std::path::Path;

fn main() {
    // Read when the script runs, not when it is compiled: a build script's
    // binary is shared by clones that build into one target folder.
    let manifest = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let dir = Path::new(&manifest).join("page");
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("psao-web's page folder {}: {e}", dir.display()))
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_file())
        .filter_map(|e| e.file_name().into_string().ok())
        .collect();
    assert!(
        names.iter().any(|n| n == "index.html"),
        "psao-web's page folder {} has no index.html",
        dir.display()
    );
    names.sort();
    let mut out = String::from(
        "/// The page's files: (name, bytes).\npub(crate) const PAGE: &[(&str, &[u8])] = &[\n",
    );
    for n in &names {
        let path = dir.join(n);
        println!("cargo:rerun-if-changed={}", path.display());
        writeln!(
            out,
            "    ({n:?}, include_bytes!({:?})),",
            path.display().to_string()
        )
        .unwrap();
    }
    out.push_str("];\n");
    let dest = Path::new(&std::env::var("OUT_DIR").unwrap()).join("page_files.rs");
    std::fs::write(dest, out).unwrap();
}
