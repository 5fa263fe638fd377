//! What a render process drew, kept in its memory and served to the other processes of its node
//! through iceoryx2 request–response: a judge (or any reader) asks for an artifact by its content
//! address (the SHA-256 the artifact store names it by) and gets the bytes in a shared-memory
//! response, read in place, with no file in between.
//!
//! Every keeping process serves the same node-wide service, [`SERVICE`]: a request reaches all of
//! them, the one that keeps the artifact answers with it and the others with an empty response.
//! The reader checks the bytes against the address it asked for, so a wrong answer can never be
//! taken for the artifact. An artifact nobody on the node keeps (drawn on another node, evicted,
//! or its process died) is `None`: the reader then reads the artifact store's copy.

use std::collections::{HashMap, VecDeque};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use iceoryx2::port::client::Client;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use sha2::{Digest, Sha256};

use crate::{BusError, FrameBus, err};

/// The node-wide service every keeping process serves.
pub const SERVICE: &str = "assay/artifacts";
/// Keeping processes (servers) and readers (clients) on one node.
const MAX_SERVERS: usize = 16;
const MAX_CLIENTS: usize = 32;

/// A content address: the raw SHA-256 of the bytes.
pub type Address = [u8; 32];

/// The address inside an artifact key `<kind>/<64 hex digits>.<ext>`; `None` for any other key.
pub fn address_of_key(key: &str) -> Option<Address> {
    let name = key.rsplit('/').next()?;
    let hex = name.split('.').next()?;
    if hex.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, byte) in out.iter_mut().enumerate() {
        *byte = u8::from_str_radix(hex.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(out)
}

type ArtifactServer = Server<ipc::Service, Address, (), [u8], ()>;
type ArtifactClient = Client<ipc::Service, Address, (), [u8], ()>;

impl FrameBus {
    fn artifacts(
        &self,
    ) -> Result<
        iceoryx2::service::port_factory::request_response::PortFactory<
            ipc::Service,
            Address,
            (),
            [u8],
            (),
        >,
        BusError,
    > {
        let name = ServiceName::new(SERVICE).map_err(|e| err("service name", e))?;
        let open = || {
            self.node
                .service_builder(&name)
                .request_response::<Address, [u8]>()
                .max_servers(MAX_SERVERS)
                .max_clients(MAX_CLIENTS)
                .max_active_requests_per_client(1)
                .max_response_buffer_size(2)
                .max_borrowed_responses_per_pending_response(1)
                .open_or_create()
        };
        match open() {
            Ok(service) => Ok(service),
            // A creator killed half-way leaves the service unusable for everyone after it:
            // remove what it left and try once more.
            Err(_) if crate::remove_orphaned_config(SERVICE) => {
                open().map_err(|e| err(&format!("opening service '{SERVICE}'"), e))
            }
            Err(e) => Err(err(&format!("opening service '{SERVICE}'"), e)),
        }
    }

    fn artifact_server(&self) -> Result<ArtifactServer, BusError> {
        self.artifacts()?
            .server_builder()
            .initial_max_slice_len(256 * 1024)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| err("creating an artifact server", e))
    }

    /// A reader of the artifacts this node's processes keep. Not `Send`: make it on the thread
    /// that reads.
    pub fn artifact_reader(&self) -> Result<ArtifactReader, BusError> {
        let client = self
            .artifacts()?
            .client_builder()
            .create()
            .map_err(|e| err("creating an artifact client", e))?;
        Ok(ArtifactReader { client })
    }
}

/// Keeps artifacts in this process's memory (at most `budget` bytes, the oldest dropped first)
/// and serves them on the node from a thread of its own.
pub struct ArtifactKeeper {
    inserts: mpsc::Sender<(Address, Vec<u8>)>,
}

impl ArtifactKeeper {
    /// Starts the serving thread; `name` names this process's iceoryx2 node.
    pub fn start(name: &str, budget: usize) -> Result<Self, BusError> {
        let (inserts, rx) = mpsc::channel::<(Address, Vec<u8>)>();
        let (ready, started) = mpsc::channel();
        let name = name.to_owned();
        std::thread::Builder::new()
            .name("artifact-keeper".into())
            .spawn(move || {
                // iceoryx2 ports belong to the thread that made them.
                let made = FrameBus::open(&name).and_then(|bus| Ok((bus.artifact_server()?, bus)));
                match made {
                    Ok((server, _bus)) => {
                        let _ = ready.send(Ok(()));
                        serve(server, rx, budget);
                    }
                    Err(e) => {
                        let _ = ready.send(Err(e));
                    }
                }
            })
            .map_err(|e| err("starting the keeper thread", e))?;
        started
            .recv()
            .map_err(|e| err("the keeper thread stopped", e))??;
        Ok(Self { inserts })
    }

    /// Keeps `bytes` under their content address (the key's); a key without one is ignored.
    pub fn keep(&self, key: &str, bytes: Vec<u8>) {
        if let Some(address) = address_of_key(key) {
            let _ = self.inserts.send((address, bytes));
        }
    }
}

fn serve(server: ArtifactServer, inserts: mpsc::Receiver<(Address, Vec<u8>)>, budget: usize) {
    let mut kept: HashMap<Address, Vec<u8>> = HashMap::new();
    let mut order: VecDeque<Address> = VecDeque::new();
    let mut bytes = 0usize;
    loop {
        let mut busy = false;
        loop {
            match inserts.try_recv() {
                Ok((address, data)) => {
                    busy = true;
                    if kept.contains_key(&address) {
                        continue;
                    }
                    bytes += data.len();
                    kept.insert(address, data);
                    order.push_back(address);
                    while bytes > budget {
                        let Some(old) = order.pop_front() else { break };
                        bytes -= kept.remove(&old).map_or(0, |d| d.len());
                    }
                }
                Err(mpsc::TryRecvError::Empty) => break,
                // The process is done with rendering: stop serving.
                Err(mpsc::TryRecvError::Disconnected) => return,
            }
        }
        while let Ok(Some(request)) = server.receive() {
            busy = true;
            let data: &[u8] = kept
                .get(request.payload())
                .map_or(&[][..], |d| d.as_slice());
            // A failed answer is a miss for the reader, who then reads the artifact store.
            if let Ok(response) = request.loan_slice_uninit(data.len()) {
                let _ = response.write_from_slice(data).send();
            }
        }
        if !busy {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Asks the node's keeping processes for artifacts by content address.
pub struct ArtifactReader {
    client: ArtifactClient,
}

impl ArtifactReader {
    /// The bytes stored under `key` if a process of this node keeps them (checked against the
    /// key's content address), else `None`. Waits at most `timeout` for the answers.
    pub fn fetch(&self, key: &str, timeout: Duration) -> Result<Option<Vec<u8>>, BusError> {
        let Some(address) = address_of_key(key) else {
            return Ok(None);
        };
        let pending = self
            .client
            .send_copy(address)
            .map_err(|e| err("sending a request", e))?;
        let servers = pending.number_of_server_connections();
        let mut answered = 0;
        let deadline = Instant::now() + timeout;
        while answered < servers && Instant::now() < deadline {
            match pending.receive().map_err(|e| err("receiving", e))? {
                Some(response) => {
                    answered += 1;
                    let data = response.payload();
                    if !data.is_empty() && <[u8; 32]>::from(Sha256::digest(data)) == address {
                        return Ok(Some(data.to_vec()));
                    }
                }
                None => std::thread::sleep(Duration::from_micros(100)),
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key_of(bytes: &[u8]) -> String {
        let hex: String = Sha256::digest(bytes)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        format!("imagery/{hex}.png")
    }

    #[test]
    fn a_kept_artifact_is_served_by_address_and_an_unknown_one_is_a_miss() {
        let keeper =
            ArtifactKeeper::start(&format!("keeper-test-{}", std::process::id()), 1 << 20).unwrap();
        let frame = vec![7u8; 300_000];
        let key = key_of(&frame);
        keeper.keep(&key, frame.clone());
        let bus = FrameBus::open(&format!("reader-test-{}", std::process::id())).unwrap();
        let reader = bus.artifact_reader().unwrap();
        let t = Duration::from_secs(2);
        // The keeper takes the insert on its own thread: ask until it is there.
        let deadline = Instant::now() + Duration::from_secs(5);
        let got = loop {
            if let Some(got) = reader.fetch(&key, t).unwrap() {
                break got;
            }
            assert!(Instant::now() < deadline, "the kept artifact never came");
            std::thread::sleep(Duration::from_millis(10));
        };
        assert_eq!(got, frame);
        assert_eq!(reader.fetch(&key_of(b"never kept"), t).unwrap(), None);
        assert_eq!(reader.fetch("imagery/not-an-address.png", t).unwrap(), None);
        // Over budget, the oldest goes first.
        let second = vec![9u8; 900_000];
        keeper.keep(&key_of(&second), second.clone());
        let deadline = Instant::now() + Duration::from_secs(5);
        while reader.fetch(&key, t).unwrap().is_some() {
            assert!(
                Instant::now() < deadline,
                "the oldest artifact was never dropped"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(reader.fetch(&key_of(&second), t).unwrap(), Some(second));
    }
}
