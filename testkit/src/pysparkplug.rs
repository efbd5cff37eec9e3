//! Runs `tests/interop/sparkplug_decode.py` (pysparkplug, a Sparkplug decoder not written in this project) on
//! messages in publishing order and returns what it makes of each, as JSON.

use std::io::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};

use serde_json::{json, Value as Json};

/// pysparkplug's view of `(topic, payload)` messages (data decoded against the births).
pub fn decode_with_pysparkplug<'a>(
    messages: impl IntoIterator<Item = (&'a str, &'a [u8])>,
) -> Vec<Json> {
    let input: Vec<Json> = messages
        .into_iter()
        .map(|(topic, payload)| json!({ "topic": topic, "hex": super::hex::encode(payload) }))
        .collect();
    // The script lives with the workspace's interop scripts, two levels above this crate.
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/interop/sparkplug_decode.py");
    let mut child = Command::new("python3")
        .arg(&script)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|error| panic!("python3 could not be started: {error}"));
    if let Some(mut stdin) = child.stdin.take() {
        let text = serde_json::to_vec(&input).unwrap_or_default();
        stdin
            .write_all(&text)
            .unwrap_or_else(|error| panic!("writing to the decoder: {error}"));
    }
    let output = child
        .wait_with_output()
        .unwrap_or_else(|error| panic!("the decoder: {error}"));
    assert!(
        output.status.success(),
        "the pysparkplug decoder failed ({}); it needs `pip install pysparkplug==0.6.1`:\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout)
        .unwrap_or_else(|error| panic!("decoder output is no JSON list: {error}"))
}
