//! A cluster with a token: clients and workers without it (or with another) are refused, those
//! with it work, and the token appears in no log. Role keys: each refused where its role does not
//! belong and allowed where it does; credential files rotated without a restart.

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

/// A role's key as `assay token derive --role <role>` prints it from the cluster token in the
/// environment (the token is never a flag).
fn derived_key(dir: &std::path::Path, token: &str, role: &str) -> String {
    let out = std::process::Command::new(bin())
        .args(["token", "derive", "--role", role])
        .env("ASSAY_CLUSTER_TOKEN", token)
        .current_dir(dir)
        .output()
        .unwrap();
    let key = ok(&out).trim().to_owned();
    let expected = Token::new(token)
        .unwrap()
        .role_key(assay_proto::auth::Access::parse_role(role).unwrap());
    assert_eq!(key, expected.expose(), "{role}");
    key
}

/// A coordinator started with the environment `env`; returns it, its address and its telemetry
/// endpoint.
fn protected_coordinator(
    dir: &std::path::Path,
    env: &[(&str, &str)],
    extra: &[&str],
) -> (Proc, String, String) {
    let addr_file = dir.join("coordinator.addr");
    let (store, artifacts) = (dir.join("jobs.db"), dir.join("artifacts"));
    let mut args = vec![
        "coordinator",
        "--listen",
        "127.0.0.1:0",
        "--store",
        store.to_str().unwrap(),
        "--artifacts",
        artifacts.to_str().unwrap(),
        "--addr-file",
        addr_file.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let coordinator = Proc::spawn_env("coordinator", &args, dir, env);
    wait_for_file(&coordinator, &addr_file, "the coordinator did not start");
    let announced = std::fs::read_to_string(&addr_file).unwrap();
    let mut lines = announced.lines();
    let addr = format!("http://{}", lines.next().unwrap().trim());
    (coordinator, addr, lines.next().unwrap_or("off").to_owned())
}

fn sim_worker(dir: &std::path::Path, addr: &str, id: &str, env: &[(&str, &str)]) -> Proc {
    Proc::spawn_env(
        id,
        &[
            "worker",
            "--coordinator",
            addr,
            "--roles",
            "sim",
            "--worker-id",
            id,
        ],
        dir,
        env,
    )
}

/// Asserts that every log in `dir` shows none of `secrets`.
fn no_log_shows(dir: &std::path::Path, secrets: &[&str]) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "log") {
            let text = std::fs::read_to_string(&path).unwrap();
            for s in secrets {
                assert!(!text.contains(s), "{} shows a key", path.display());
            }
        }
    }
}

/// Every role's key against every group of calls: refused where it does not belong
/// (`PERMISSION_DENIED`, a worker process exits saying why), allowed where it does.
#[test]
fn each_roles_key_is_refused_where_it_does_not_belong() {
    use tonic::Code::PermissionDenied;
    let dir = tempfile::tempdir().unwrap();
    let token_file = dir.path().join("cluster-token");
    std::fs::write(&token_file, format!("{TOKEN}\n")).unwrap();
    let (mut coordinator, addr, telemetry) = protected_coordinator(
        dir.path(),
        &[("ASSAY_CLUSTER_TOKEN_FILE", token_file.to_str().unwrap())],
        &[],
    );
    let worker_key = derived_key(dir.path(), TOKEN, "worker");
    let submitter_key = derived_key(dir.path(), TOKEN, "submitter");
    let viewer_key = derived_key(dir.path(), TOKEN, "viewer");

    // WorkerSession: a worker presenting a submitter's or a viewer's key (the wrong Secret
    // mounted) is refused and exits saying why; one with the worker key (from a file) joins.
    for (name, key, what) in [
        ("as-submitter", &submitter_key, "a submitter key"),
        ("as-viewer", &viewer_key, "a viewer key"),
    ] {
        let mut w = sim_worker(dir.path(), &addr, name, &[("ASSAY_WORKER_TOKEN", key)]);
        assert!(!w.wait_exit(Duration::from_secs(30)).success());
        let log = w.log_text();
        assert!(
            log.contains("refused this worker")
                && log.contains(&format!("{what} may not call WorkerSession/Session")),
            "{log}"
        );
    }
    let worker_key_file = dir.path().join("worker-key");
    std::fs::write(&worker_key_file, &worker_key).unwrap();
    let _member = sim_worker(
        dir.path(),
        &addr,
        "member",
        &[("ASSAY_WORKER_TOKEN_FILE", worker_key_file.to_str().unwrap())],
    );

    runtime().block_on(async {
        // Session over gRPC directly, for every key that is not a worker's.
        for key in [&submitter_key, &viewer_key] {
            let channel = assay_proto::channel::connect("coordinator", &addr, &Default::default())
                .await
                .unwrap();
            let mut s: pb::worker_session_client::WorkerSessionClient<_> =
                assay_proto::channel::client(
                    channel,
                    Some(Token::new(key).unwrap()),
                    assay_proto::MAX_MESSAGE_BYTES,
                );
            let e = s
                .session(tonic::codegen::tokio_stream::empty::<pb::WorkerMessage>())
                .await
                .unwrap_err();
            assert_eq!(e.code(), PermissionDenied, "{e}");
        }
        let submit = || pb::SubmitBatchRequest {
            tasks: documents(&["tests/fixtures/small/small-stack-two-blocks.yaml"]),
            seeds: vec![0, 1],
            ..Default::default()
        };
        // The submitter submits; the worker key runs its shards.
        let mut submitter = client_with(&addr, Some(&submitter_key)).await;
        let sub = submitter.submit_batch(submit()).await.unwrap().into_inner();
        let id = || pb::GetBatchRequest {
            batch_id: sub.batch_id.clone(),
        };
        let report = || pb::GetReportRequest {
            batch_id: sub.batch_id.clone(),
        };
        // Refused: worker and viewer keys on submit and cancel; the worker key on every read.
        for key in [&worker_key, &viewer_key] {
            let mut c = client_with(&addr, Some(key)).await;
            let e = c.submit_batch(submit()).await.unwrap_err();
            assert_eq!(e.code(), PermissionDenied, "{e}");
            assert!(
                e.message().contains("may not call Coordinator/SubmitBatch"),
                "{e}"
            );
            let e = c.cancel_batch(id()).await.unwrap_err();
            assert_eq!(e.code(), PermissionDenied, "{e}");
        }
        let mut w = client_with(&addr, Some(&worker_key)).await;
        assert_eq!(
            w.get_batch(id()).await.unwrap_err().code(),
            PermissionDenied
        );
        assert_eq!(
            w.list_batches(pb::ListBatchesRequest {})
                .await
                .unwrap_err()
                .code(),
            PermissionDenied
        );
        assert_eq!(
            w.watch_batch(id()).await.unwrap_err().code(),
            PermissionDenied
        );
        let e = w.get_report(report()).await.unwrap_err();
        assert_eq!(e.code(), PermissionDenied);
        assert!(
            e.message()
                .contains("a worker key may not call Coordinator/GetReport"),
            "{e}"
        );
        // Allowed: the viewer and the submitter read status, progress and the report.
        let deadline = Instant::now() + Duration::from_secs(120);
        let mut viewer = client_with(&addr, Some(&viewer_key)).await;
        loop {
            let st = viewer.get_batch(id()).await.unwrap().into_inner();
            if st.state == pb::BatchState::Completed as i32 {
                assert_eq!((st.shards_done, st.workers_connected), (2, 1));
                break;
            }
            assert!(Instant::now() < deadline, "{st:?}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        for c in [&mut viewer, &mut submitter] {
            assert_eq!(
                c.list_batches(pb::ListBatchesRequest {})
                    .await
                    .unwrap()
                    .into_inner()
                    .batches
                    .len(),
                1
            );
            let mut watch = c.watch_batch(id()).await.unwrap().into_inner();
            assert!(watch.message().await.unwrap().is_some());
            let r = c.get_report(report()).await.unwrap().into_inner();
            assert!(r.r#final && r.report_json.contains(&sub.batch_id));
        }
        // The submitter cancels (a second batch).
        let second = submitter.submit_batch(submit()).await.unwrap().into_inner();
        submitter
            .cancel_batch(pb::GetBatchRequest {
                batch_id: second.batch_id.clone(),
            })
            .await
            .unwrap();
    });

    // The CLI reads a role's key from its variable: a viewer lists, and is refused a submit.
    let viewer_env = [("ASSAY_VIEWER_TOKEN", viewer_key.as_str())];
    let status = Proc::spawn_env(
        "viewer-status",
        &["status", "--coordinator", &addr],
        dir.path(),
        &viewer_env,
    )
    .wait_exit(Duration::from_secs(30));
    assert!(status.success());
    let mut submit = Proc::spawn_env(
        "viewer-submit",
        &[
            "submit",
            "--coordinator",
            &addr,
            repo()
                .join("tests/fixtures/small/small-stack-two-blocks.yaml")
                .to_str()
                .unwrap(),
        ],
        dir.path(),
        &viewer_env,
    );
    assert!(!submit.wait_exit(Duration::from_secs(30)).success());
    assert!(
        submit
            .log_text()
            .contains("a viewer key may not call Coordinator/SubmitBatch"),
        "{}",
        submit.log_text()
    );

    // Telemetry: the viewer's key watches; the member worker (its worker key) publishes.
    let top_args = [
        "top",
        "--telemetry",
        &telemetry,
        "--json",
        "--duration",
        "4",
    ];
    let mut top = Proc::spawn_env("viewer-top", &top_args, dir.path(), &viewer_env);
    assert!(
        top.wait_exit(Duration::from_secs(60)).success(),
        "{}",
        top.log_text()
    );
    assert!(
        top.log_text()
            .lines()
            .any(|l| l.starts_with("{\"key\":\"assay/local/workers/member/stats\"")),
        "the viewer saw no statistics from the member worker:\n{}",
        top.log_text()
    );

    coordinator.term(Duration::from_secs(5));
    no_log_shows(
        dir.path(),
        &[TOKEN, &worker_key, &submitter_key, &viewer_key],
    );
}

/// The coordinator re-reads its credential files, swapped as kubelet swaps a mounted Secret (a
/// `..data` symlink renamed over): the new keys are taken and the old refused without a restart;
/// a bad file leaves the keys as they were.
#[test]
fn rotated_credential_files_are_taken_without_a_restart() {
    use std::os::unix::fs::symlink;
    let dir = tempfile::tempdir().unwrap();
    let secret = dir.path().join("secret");
    std::fs::create_dir(&secret).unwrap();
    let (old_token, new_token) = (TOKEN, "r0tated-cluster-token-9876543210");
    let (old_viewer, new_viewer) = ("old-viewer-key-0123456789", "new-viewer-key-9876543210");
    // One version of the Secret: its files in a folder, `..data` pointing at it.
    let version = |n: u32, token: &str, viewer: &str| {
        let v = secret.join(format!("..v{n}"));
        std::fs::create_dir(&v).unwrap();
        std::fs::write(v.join("cluster-token"), format!("{token}\n")).unwrap();
        std::fs::write(v.join("viewer-key"), viewer).unwrap();
        let tmp = secret.join("..data_tmp");
        symlink(format!("..v{n}"), &tmp).unwrap();
        std::fs::rename(&tmp, secret.join("..data")).unwrap();
    };
    version(1, old_token, old_viewer);
    for f in ["cluster-token", "viewer-key"] {
        symlink(format!("..data/{f}"), secret.join(f)).unwrap();
    }
    let (mut coordinator, addr, _) = protected_coordinator(
        dir.path(),
        &[
            (
                "ASSAY_CLUSTER_TOKEN_FILE",
                secret.join("cluster-token").to_str().unwrap(),
            ),
            (
                "ASSAY_VIEWER_TOKEN_FILE",
                secret.join("viewer-key").to_str().unwrap(),
            ),
        ],
        &["--telemetry", "off"],
    );
    let submitter = |token: &str| {
        Token::new(token)
            .unwrap()
            .role_key(assay_proto::auth::Access::Submitter)
            .expose()
            .to_owned()
    };
    let (old_submitter, new_submitter) = (submitter(old_token), submitter(new_token));
    runtime().block_on(async {
        let list = |key: String| {
            let addr = addr.clone();
            async move {
                client_with(&addr, Some(&key))
                    .await
                    .list_batches(pb::ListBatchesRequest {})
                    .await
                    .map(|_| ())
                    .map_err(|e| e.code())
            }
        };
        for key in [
            old_token.to_owned(),
            old_submitter.clone(),
            old_viewer.to_owned(),
        ] {
            assert_eq!(list(key).await, Ok(()));
        }
        assert!(list(new_token.to_owned()).await.is_err());

        version(2, new_token, new_viewer);
        let deadline = Instant::now() + Duration::from_secs(20);
        while list(new_token.to_owned()).await.is_err() {
            assert!(
                Instant::now() < deadline,
                "the rotated token was not taken:\n{}",
                coordinator.log_text()
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        for key in [
            new_token.to_owned(),
            new_submitter.clone(),
            new_viewer.to_owned(),
        ] {
            assert_eq!(list(key).await, Ok(()));
        }
        // The old keys, the one derived from the old token included, are refused.
        for key in [
            old_token.to_owned(),
            old_submitter.clone(),
            old_viewer.to_owned(),
        ] {
            assert_eq!(list(key).await, Err(tonic::Code::Unauthenticated));
        }

        // A bad version (a key too short) is refused and the keys stay.
        version(3, new_token, "short");
        tokio::time::sleep(Duration::from_secs(5)).await;
        assert_eq!(list(new_viewer.to_owned()).await, Ok(()));
        assert_eq!(list(new_token.to_owned()).await, Ok(()));
    });
    let log = coordinator.log_text();
    assert!(log.contains("credentials changed"), "{log}");
    assert!(
        log.contains("credential files unreadable")
            && log.contains("$ASSAY_VIEWER_TOKEN_FILE names"),
        "{log}"
    );
    coordinator.term(Duration::from_secs(5));
    no_log_shows(
        dir.path(),
        &[
            old_token,
            new_token,
            old_viewer,
            new_viewer,
            &old_submitter,
            &new_submitter,
        ],
    );
}
