//! A batch larger than one gRPC message: GenSim's library, imported with its per-seed layouts
//! (15.5 MB of YAML, written as `assay import --out` writes it) and submitted seven times over
//! with the tasks renamed (109 MB of task documents), goes to a real coordinator by
//! `SubmitBatchStream` and is accepted whole; the same documents in one `SubmitBatch` message are
//! refused for their size.

use crate::common::*;
use assay_proto::v1 as pb;

#[test]
fn a_batch_larger_than_a_message_is_streamed_and_accepted_whole() {
    let dir = tempfile::tempdir().unwrap();
    let corpus = repo().join("../shared/corpora/gensim-library");
    let specs: Vec<(String, String)> = write_gensim_specs(&dir.path().join("library"), usize::MAX)
        .into_iter()
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read_to_string(&p).unwrap(),
            )
        })
        .collect();
    assert!(specs.len() > 80, "{} imported", specs.len());
    let batch = dir.path().join("batch");
    std::fs::create_dir_all(&batch).unwrap();
    let mut bytes = 0;
    for copy in 0..7 {
        for (file, text) in &specs {
            let renamed: String = text
                .lines()
                .map(|l| match l.strip_prefix("id: ") {
                    Some(id) => format!("id: {id}-copy{copy}\n"),
                    None => format!("{l}\n"),
                })
                .collect();
            assert_ne!(&renamed, text);
            bytes += renamed.len();
            std::fs::write(batch.join(format!("{copy}-{file}")), renamed).unwrap();
        }
    }
    let tasks = 7 * specs.len();
    assert!(
        bytes > assay_proto::MAX_MESSAGE_BYTES,
        "{bytes} bytes: not larger than a message"
    );

    let (_coordinator, addr) = coordinator(dir.path(), "127.0.0.1:0", &[]);
    let out = assay(&[
        "submit",
        "--coordinator",
        &addr,
        "--seeds",
        "1",
        "--asset-root",
        corpus.join("assets").to_str().unwrap(),
        batch.to_str().unwrap(),
    ]);
    let stdout = ok(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!(
            "{tasks} tasks accepted, 0 rejected, {tasks} shards"
        )),
        "{stderr}"
    );
    let batch_id = stdout.lines().last().unwrap().trim().to_owned();
    runtime().block_on(async {
        let mut c = client(&addr).await;
        let status = c
            .get_batch(pb::GetBatchRequest {
                batch_id: batch_id.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(status.shards_total as usize, tasks, "{status:?}");
        assert_eq!(status.invalid_tasks, 0);

        // In one message, the same documents do not pass.
        let docs: Vec<pb::TaskDocument> = std::fs::read_dir(&batch)
            .unwrap()
            .map(|e| {
                let p = e.unwrap().path();
                pb::TaskDocument {
                    origin: p.display().to_string(),
                    format: String::new(),
                    content: std::fs::read_to_string(&p).unwrap(),
                }
            })
            .collect();
        let e = c
            .max_encoding_message_size(usize::MAX)
            .submit_batch(pb::SubmitBatchRequest {
                name: "one message".into(),
                tasks: docs,
                seeds: vec![0],
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), tonic::Code::OutOfRange, "{e}");
    });
}
