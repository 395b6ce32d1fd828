//! With the `sim` feature, gives the binaries an rpath to the directory that
//! `sim/fetch-mujoco.sh` printed as `MUJOCO_DYNAMIC_LINK_DIR`, so `marionette` finds
//! `libmujoco.so` without `LD_LIBRARY_PATH`.
fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if std::env::var_os("CARGO_FEATURE_SIM").is_some() {
        if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
            println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        }
    }
}
