//! `assay-framebus`: camera frames between the processes of one node, through iceoryx2
//! publish–subscribe in shared memory. A publisher loans a sample and writes the frame into it in
//! place (the renderer's readback goes straight there); subscribers read it in place. Nothing is
//! copied between processes.
//!
//! A dead or slow subscriber never blocks a publisher: the services use iceoryx2's safe overflow
//! (a full subscriber queue drops its oldest frame), and dead nodes' shared-memory resources are
//! removed when a bus is opened. Across nodes frames travel encoded in gRPC or as artifacts.
//!
//! Owns: the frame header layout and the iceoryx2 settings. Never renders or simulates.

pub mod cache;

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;

/// Describes the frame that follows it in the same shared-memory sample.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("assay::FrameHeader")]
pub struct FrameHeader {
    /// The shard (episode) the frame belongs to.
    pub episode: u64,
    /// Physics step of the state drawn.
    pub step: u64,
    /// `CLOCK_MONOTONIC` at publication (ns): comparable between processes of a node.
    pub timestamp_ns: u64,
    /// Index of the camera in the task's camera list.
    pub camera: u32,
    /// One of [`format`].
    pub format: u32,
    pub width: u32,
    pub height: u32,
    /// Bytes per row.
    pub stride: u32,
    pub reserved: u32,
}

/// Pixel formats of frames.
pub mod format {
    pub const RGBA8: u32 = 1;
    /// f32 metres along the camera axis.
    pub const DEPTH_F32: u32 = 2;
    /// u32 segment ids.
    pub const SEGMENT_U32: u32 = 3;
}

#[derive(Debug, thiserror::Error)]
#[error("frame bus: {0}")]
pub struct BusError(String);

pub(crate) fn err(what: &str, e: impl std::fmt::Debug) -> BusError {
    BusError(format!("{what}: {e:?}"))
}

/// Frames queued per subscriber before the oldest is dropped.
pub const QUEUE: usize = 2;
/// Subscribers per camera stream (recorder, judge, policy, …).
pub const MAX_SUBSCRIBERS: usize = 4;

/// `CLOCK_MONOTONIC` in nanoseconds.
pub fn monotonic_ns() -> u64 {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).expect("monotonic clock");
    t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64
}

/// One process's handle on the node's frame bus.
pub struct FrameBus {
    pub(crate) node: Node<ipc::Service>,
}

/// A static service configuration still writable this long after it was written is an orphan:
/// a live creator finishes it (and makes it read-only) within milliseconds.
const ORPHAN_AGE: std::time::Duration = std::time::Duration::from_secs(5);

/// Removes service `service`'s static configuration when the process creating it died half-way
/// (killed -9): iceoryx2 0.10 leaves the file writable and then refuses to open or create the
/// service for every later process — a frame stream that never comes back, an artifact cache
/// whose every picture comes from the store (iceoryx2 issue 1584; 0.10 has no API to remove
/// it). Only a file that names this service, is still writable and is older than
/// [`ORPHAN_AGE`] is removed. Whether one was.
pub(crate) fn remove_orphaned_config(service: &str) -> bool {
    let c = config();
    let dir = std::path::PathBuf::from(c.global.root_path().to_string())
        .join(c.global.service.directory.to_string());
    let (prefix, suffix) = (
        c.global.prefix.to_string(),
        c.global.service.static_config_storage_suffix.to_string(),
    );
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return false;
    };
    let mut removed = false;
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().into_owned();
        let Ok(meta) = entry.metadata() else {
            continue;
        };
        let orphan = file.starts_with(&prefix)
            && file.ends_with(&suffix)
            && !meta.permissions().readonly()
            && meta
                .modified()
                .ok()
                .and_then(|m| m.elapsed().ok())
                .is_some_and(|age| age > ORPHAN_AGE);
        if orphan
            && std::fs::read_to_string(entry.path())
                .is_ok_and(|t| t.contains(&format!("service_name = \"{service}\"")))
            && std::fs::remove_file(entry.path()).is_ok()
        {
            removed = true;
        }
    }
    removed
}

fn config() -> Config {
    let mut c = Config::default();
    c.global.prefix = FileName::new(b"assay_").expect("a valid file name prefix");
    c
}

impl FrameBus {
    /// Joins the bus, first removing what dead processes (kill -9) left in shared memory.
    pub fn open(name: &str) -> Result<Self, BusError> {
        set_log_level(LogLevel::Warn);
        let c = config();
        Node::<ipc::Service>::list(&c, |state| {
            if let NodeState::<ipc::Service>::Dead(view) = state {
                let _ = view.try_remove_stale_resources();
            }
            CallbackProgression::Continue
        })
        .map_err(|e| err("listing nodes", e))?;
        let node = NodeBuilder::new()
            .name(&NodeName::new(name).map_err(|e| err("node name", e))?)
            .config(&c)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| err("creating the node", e))?;
        Ok(Self { node })
    }

    fn service(
        &self,
        stream: &str,
    ) -> Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<
            ipc::Service,
            [u8],
            FrameHeader,
        >,
        BusError,
    > {
        let name = ServiceName::new(stream).map_err(|e| err("stream name", e))?;
        let open = || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .user_header::<FrameHeader>()
                .max_publishers(2)
                .max_subscribers(MAX_SUBSCRIBERS)
                .subscriber_max_buffer_size(QUEUE)
                .subscriber_max_borrowed_samples(2)
                .history_size(0)
                // A full queue drops its oldest frame: a dead or slow reader never blocks a camera.
                .enable_safe_overflow(true)
                .open_or_create()
        };
        match open() {
            Ok(service) => Ok(service),
            // A creator killed half-way leaves the stream unusable: remove what it left, once.
            Err(_) if remove_orphaned_config(stream) => {
                open().map_err(|e| err(&format!("opening stream '{stream}'"), e))
            }
            Err(e) => Err(err(&format!("opening stream '{stream}'"), e)),
        }
    }

    /// A publisher for frames of up to `max_frame_bytes` (larger ones grow the segment).
    pub fn publisher(
        &self,
        stream: &str,
        max_frame_bytes: usize,
    ) -> Result<FramePublisher, BusError> {
        let publisher = self
            .service(stream)?
            .publisher_builder()
            .initial_max_slice_len(max_frame_bytes.max(1))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(2)
            .create()
            .map_err(|e| err("creating a publisher", e))?;
        Ok(FramePublisher { publisher })
    }

    pub fn subscriber(&self, stream: &str) -> Result<FrameSubscriber, BusError> {
        let subscriber = self
            .service(stream)?
            .subscriber_builder()
            .create()
            .map_err(|e| err("creating a subscriber", e))?;
        Ok(FrameSubscriber { subscriber })
    }
}

/// Publishes frames of one stream. Not `Send`: create it on the thread that renders.
pub struct FramePublisher {
    publisher: Publisher<ipc::Service, [u8], FrameHeader>,
}

impl FramePublisher {
    /// Loans `len` bytes of shared memory, lets `fill` write the frame there in place, stamps the
    /// header and sends it. Returns how many subscribers it reached.
    pub fn publish(
        &self,
        header: FrameHeader,
        len: usize,
        fill: impl FnOnce(&mut [u8]),
    ) -> Result<usize, BusError> {
        let mut sample = self.loan(len)?;
        fill(sample.payload_mut());
        Self::send(sample, header)
    }

    /// Like [`publish`](Self::publish), but `fill` may fail: then nothing is sent (the sample
    /// goes back to the pool) and its error is returned inside `Ok`.
    pub fn try_publish<T, E>(
        &self,
        header: FrameHeader,
        len: usize,
        fill: impl FnOnce(&mut [u8]) -> Result<T, E>,
    ) -> Result<Result<(T, usize), E>, BusError> {
        let mut sample = self.loan(len)?;
        let value = match fill(sample.payload_mut()) {
            Ok(v) => v,
            Err(e) => return Ok(Err(e)),
        };
        Ok(Ok((value, Self::send(sample, header)?)))
    }

    // `loan` and `send` are not generic, so they are compiled here, with this crate's
    // optimisation, not in every caller of `publish`: a debug build's sim worker spent a quarter
    // of its time zeroing loaned frames one byte per call, compiled in assay-worker (perf, the
    // demo; ARCHITECTURE.md, "Build").

    /// `len` zeroed bytes of shared memory.
    fn loan(&self, len: usize) -> Result<SampleMut<ipc::Service, [u8], FrameHeader>, BusError> {
        self.publisher
            .loan_slice(len)
            .map_err(|e| err("loaning a sample", e))
    }

    fn send(
        mut sample: SampleMut<ipc::Service, [u8], FrameHeader>,
        mut header: FrameHeader,
    ) -> Result<usize, BusError> {
        header.timestamp_ns = monotonic_ns();
        *sample.user_header_mut() = header;
        sample.send().map_err(|e| err("sending", e))
    }
}

/// Receives frames of one stream. Not `Send`: create it on the thread that reads.
pub struct FrameSubscriber {
    subscriber: Subscriber<ipc::Service, [u8], FrameHeader>,
}

impl FrameSubscriber {
    /// The next queued frame, read in place by `read`, or `None` if none is waiting.
    pub fn receive<R>(
        &self,
        read: impl FnOnce(&FrameHeader, &[u8]) -> R,
    ) -> Result<Option<R>, BusError> {
        match self.subscriber.receive().map_err(|e| err("receiving", e))? {
            Some(sample) => Ok(Some(read(sample.user_header(), sample.payload()))),
            None => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;
    use std::time::{Duration, SystemTime};

    /// The static configuration file of service `name`, if there is one.
    fn config_file(name: &str) -> Option<std::path::PathBuf> {
        let c = config();
        let dir = std::path::PathBuf::from(c.global.root_path().to_string())
            .join(c.global.service.directory.to_string());
        std::fs::read_dir(dir).ok()?.flatten().find_map(|e| {
            std::fs::read_to_string(e.path())
                .is_ok_and(|t| t.contains(&format!("service_name = \"{name}\"")))
                .then(|| e.path())
        })
    }

    /// What a creator killed -9 half-way through creating a stream leaves: the stream's static
    /// configuration, still writable, and nothing else. The bus removes it — only once it is
    /// older than a live creator could be — and the stream works again.
    #[test]
    fn a_stream_left_half_created_by_a_killed_process_is_recovered() {
        let stream = format!("test/orphan-{}", std::process::id());
        let bus = FrameBus::open(&format!("orphan-test-{}", std::process::id())).unwrap();
        let publisher = bus.publisher(&stream, 64).unwrap();
        let file = config_file(&stream).expect("the stream's static configuration");
        let text = std::fs::read(&file).unwrap();
        assert!(
            std::fs::metadata(&file).unwrap().permissions().readonly(),
            "a finished configuration is read-only"
        );
        drop(publisher);
        drop(bus);
        assert!(
            config_file(&stream).is_none(),
            "the stream is gone with its last port"
        );

        // The orphan: the same configuration, writable, with no dynamic part.
        std::fs::write(&file, &text).unwrap();
        std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o600)).unwrap();
        let bus = FrameBus::open(&format!("orphan-test-{}-2", std::process::id())).unwrap();
        // Just written, it may be a creator at work: left alone, and the stream cannot open.
        assert!(!remove_orphaned_config(&stream));
        assert!(file.exists());
        assert!(
            bus.publisher(&stream, 64).is_err(),
            "iceoryx2 refuses a service whose static configuration was never finished"
        );
        // Older than a live creator could be: removed, and the stream opens again.
        std::fs::File::options()
            .write(true)
            .open(&file)
            .unwrap()
            .set_modified(SystemTime::now() - Duration::from_secs(60))
            .unwrap();
        // A file that names another service is not touched.
        assert!(!remove_orphaned_config(&format!("{stream}-other")));
        assert!(file.exists());
        let publisher = bus.publisher(&stream, 64).unwrap();
        let subscriber = bus.subscriber(&stream).unwrap();
        let header = FrameHeader::default();
        publisher
            .publish(header, 3, |b| b.copy_from_slice(&[1, 2, 3]))
            .unwrap();
        let got = subscriber.receive(|_, b| b.to_vec()).unwrap();
        assert_eq!(got.as_deref(), Some(&[1u8, 2, 3][..]));
        let file = config_file(&stream).expect("the stream's new configuration");
        assert!(std::fs::metadata(&file).unwrap().permissions().readonly());
    }
}
