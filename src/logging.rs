//! The one place the tracing subscriber is set up.

use tracing_subscriber::EnvFilter;

pub fn init(format: &str) {
    // zenoh's own crates are chatty at info (session ids, link events): warnings only by default.
    let default = "info,zenoh=warn,zenoh_transport=warn,zenoh_link_tcp=warn,zenoh_link_commons=warn,zenoh_config=warn,zenoh_runtime=warn,zenoh_net=warn,zenoh_session=warn";
    let filter = EnvFilter::try_from_env("ASSAY_LOG").unwrap_or_else(|_| EnvFilter::new(default));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false);
    if format == "json" {
        builder.json().init();
    } else {
        builder.init();
    }
}
