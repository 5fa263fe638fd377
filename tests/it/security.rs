//! A cluster with a token: clients and workers without it (or with another) are refused, those
//! with it work, and the token appears in no log.

use std::time::{Duration, Instant};

use crate::common::*;
use assay_proto::auth::Token;
use assay_proto::v1 as pb;

const TOKEN: &str = "s3cr3t-cluster-token-0123456789";

async fn client_with(
    addr: &str,
    token: Option<&str>,
) -> pb::coordinator_client::CoordinatorClient<assay_proto::auth::Channel> {
    let channel = assay_proto::channel::connect("coordinator", addr, &Default::default())
        .await
        .unwrap();
    assay_proto::channel::client(
        channel,
        token.map(|t| Token::new(t).unwrap()),
        assay_proto::MAX_MESSAGE_BYTES,
    )
}

#[test]
fn without_the_cluster_token_clients_and_workers_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    // The coordinator reads the token from a file (as from a mounted Secret).
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, format!("{TOKEN}\n")).unwrap();
    let mut coordinator = Proc::spawn_env(
        "coordinator",
        &[
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--store",
            dir.path().join("jobs.db").to_str().unwrap(),
            "--artifacts",
            dir.path().join("artifacts").to_str().unwrap(),
            "--addr-file",
            dir.path().join("coordinator.addr").to_str().unwrap(),
        ],
        dir.path(),
        &[("ASSAY_CLUSTER_TOKEN_FILE", token_file.to_str().unwrap())],
    );
    wait_for_file(
        &coordinator,
        &dir.path().join("coordinator.addr"),
        "the coordinator did not start",
    );
    let announced = std::fs::read_to_string(dir.path().join("coordinator.addr")).unwrap();
    let addr = format!("http://{}", announced.lines().next().unwrap().trim());

    // A worker without the token is refused at registration and exits saying why.
    let mut intruder = Proc::spawn(
        "intruder",
        &[
            "worker",
            "--coordinator",
            &addr,
            "--roles",
            "sim",
            "--worker-id",
            "intruder",
        ],
        dir.path(),
    );
    let status = intruder.wait_exit(Duration::from_secs(30));
    assert!(!status.success());
    assert!(
        intruder.log_text().contains("refused this worker")
            && intruder.log_text().contains("requires the cluster token"),
        "{}",
        intruder.log_text()
    );
    // A worker with a wrong token too.
    let mut wrong = Proc::spawn_env(
        "wrong",
        &[
            "worker",
            "--coordinator",
            &addr,
            "--roles",
            "sim",
            "--worker-id",
            "wrong",
        ],
        dir.path(),
        &[("ASSAY_CLUSTER_TOKEN", "not-the-cluster-token-at-all")],
    );
    wrong.wait_exit(Duration::from_secs(30));
    assert!(
        wrong.log_text().contains("wrong cluster token"),
        "{}",
        wrong.log_text()
    );

    let _worker = Proc::spawn_env(
        "worker",
        &[
            "worker",
            "--coordinator",
            &addr,
            "--roles",
            "sim",
            "--worker-id",
            "member",
        ],
        dir.path(),
        &[("ASSAY_CLUSTER_TOKEN", TOKEN)],
    );
    runtime().block_on(async {
        // Clients without the token, or with another, get UNAUTHENTICATED on every call.
        for token in [None, Some("another-token-of-enough-length")] {
            let mut c = client_with(&addr, token).await;
            let e = c.list_batches(pb::ListBatchesRequest {}).await.unwrap_err();
            assert_eq!(e.code(), tonic::Code::Unauthenticated, "{e}");
            let e = c
                .submit_batch(pb::SubmitBatchRequest {
                    tasks: documents(&["tests/fixtures/small/small-stack-two-blocks.yaml"]),
                    seeds: vec![0],
                    ..Default::default()
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), tonic::Code::Unauthenticated, "{e}");
        }
        // With it, a batch runs on the member worker (and only on it).
        let mut c = client_with(&addr, Some(TOKEN)).await;
        let sub = c
            .submit_batch(pb::SubmitBatchRequest {
                tasks: documents(&["tests/fixtures/small/small-stack-two-blocks.yaml"]),
                seeds: vec![0, 1],
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        let deadline = Instant::now() + Duration::from_secs(120);
        loop {
            let st = c
                .get_batch(pb::GetBatchRequest {
                    batch_id: sub.batch_id.clone(),
                })
                .await
                .unwrap()
                .into_inner();
            if st.state == pb::BatchState::Completed as i32 {
                assert_eq!((st.shards_done, st.workers_connected), (2, 1));
                break;
            }
            assert!(Instant::now() < deadline, "{st:?}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    // Telemetry: the coordinator's zenoh router admits only sessions with the password derived
    // from the token. `assay top` with the token sees the member worker's statistics; without it,
    // it cannot join.
    let endpoint = announced
        .lines()
        .nth(1)
        .expect("the telemetry endpoint on line 2")
        .to_owned();
    let top_args = ["top", "--telemetry", &endpoint, "--json", "--duration", "4"];
    let mut top = Proc::spawn_env(
        "top",
        &top_args,
        dir.path(),
        &[("ASSAY_CLUSTER_TOKEN", TOKEN)],
    );
    assert!(
        top.wait_exit(Duration::from_secs(60)).success(),
        "{}",
        top.log_text()
    );
    assert!(
        top.log_text()
            .lines()
            .any(|l| l.starts_with("{\"key\":\"assay/local/workers/member/stats\"")),
        "no statistics from the member worker:\n{}",
        top.log_text()
    );
    let mut outsider = Proc::spawn("outsider-top", &top_args, dir.path());
    let status = outsider.wait_exit(Duration::from_secs(60));
    assert!(!status.success(), "{}", outsider.log_text());
    assert!(
        outsider
            .log_text()
            .contains("admits only its members: set ASSAY_CLUSTER_TOKEN"),
        "{}",
        outsider.log_text()
    );
    assert!(
        !outsider.log_text().contains("{\"key\":"),
        "an outsider saw the cluster's telemetry:\n{}",
        outsider.log_text()
    );

    // The token is in no log.
    coordinator.term(Duration::from_secs(5));
    for entry in std::fs::read_dir(dir.path()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "log") {
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(!text.contains(TOKEN), "{} shows the token", path.display());
            assert!(!text.contains("s3cr3t"), "{}", path.display());
        }
    }
}

#[test]
fn a_message_over_the_size_bound_is_refused_and_the_coordinator_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let (_c, addr) = coordinator(dir.path(), "127.0.0.1:0", &["--telemetry", "off"]);
    runtime().block_on(async {
        let mut c = client(&addr).await;
        let huge = "#".repeat(assay_proto::MAX_MESSAGE_BYTES + 1024);
        let e = c
            .submit_batch(pb::SubmitBatchRequest {
                tasks: vec![pb::TaskDocument {
                    origin: "huge.yaml".into(),
                    format: String::new(),
                    content: huge,
                }],
                seeds: vec![0],
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert!(
            matches!(
                e.code(),
                tonic::Code::OutOfRange | tonic::Code::ResourceExhausted
            ),
            "{e}"
        );
        // The coordinator is still there.
        c.list_batches(pb::ListBatchesRequest {}).await.unwrap();
    });
}
