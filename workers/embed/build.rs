//! Tests and examples of this crate find libtorch at run time through an rpath to its `lib/`
//! (torch-sys publishes the folder as `links` metadata).
fn main() {
    if let Some(lib) = std::env::var_os("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.to_string_lossy());
    }
}
