//! One entry point per input path, shared by the cargo-fuzz targets in `fuzz/` and by the corpus replay
//! in `tests/fuzz_corpus.rs`. Each hands arbitrary bytes to a decoder and checks its contract: a value
//! that passes the decoder's own validation, or an error — and, where an encoder exists, that encoding
//! the value and decoding it again gives the same value. A broken contract panics, which is what a
//! fuzzer looks for.

use std::path::Path;

use crate::daemon::config::Config;
use crate::frame::{Frame, YuyvImage};
use crate::geometry::{CameraIntrinsics, CameraPose, FieldDimensions};
use crate::protocol::control::ControlRequest;
use crate::protocol::frame_header::{FrameHeader, HEADER_SIZE};
use crate::protocol::gamecontroller::GameControlData;
use crate::protocol::lola::LolaState;
use crate::recording::FrameRecord;
use crate::refine::detect;
use crate::relocaliser::{Model, ModelContract};

/// A check: panics when its decoder breaks its contract on these bytes.
pub type Check = fn(&[u8]);

/// Each input path's check, by the name of its fuzz target and corpus directory.
pub const TARGETS: [(&str, Check); 7] = [
    ("gamecontroller", gamecontroller),
    ("lola", lola),
    ("control", control),
    ("frame", frame),
    ("model", model),
    ("recording", recording),
    ("config", config),
];

/// A GameController packet: a parsed packet encodes to bytes that parse to the same packet.
pub fn gamecontroller(bytes: &[u8]) {
    if let Ok(packet) = GameControlData::parse(bytes) {
        assert_eq!(GameControlData::parse(&packet.to_bytes()).as_ref(), Ok(&packet));
    }
}

/// A forwarded LoLA state message (msgpack): decodes or errs, never panics; the body angles it carries
/// turn the camera into a pose or an error.
pub fn lola(bytes: &[u8]) {
    if let Some(body) = LolaState::from_msgpack(bytes).ok().and_then(|state| state.body_angles()) {
        let _ = CameraPose::STANDING.on_body(&body);
    }
}

/// A control request: a parsed request serialises to JSON that parses to the same request (context
/// that was left out with an error is gone from both, so the second parse finds no error), and
/// every context value kept is within its checked range.
pub fn control(bytes: &[u8]) {
    if let Ok(mut request) = ControlRequest::parse(bytes) {
        if let ControlRequest::Relocalise(relocalise) = &mut request {
            if let Some(prior) = &relocalise.prior {
                assert!(prior.pose.validate("prior").is_ok());
            }
            if let Some(ball) = &relocalise.ball {
                assert!(ball.validate().is_ok());
            }
            relocalise.context_errors.clear();
        }
        let json = serde_json::to_vec(&request).expect("a request serialises");
        assert_eq!(ControlRequest::parse(&json), Ok(request));
    }
}

/// A forwarded frame, header then payload: a parsed header round-trips, its payload size is exactly
/// what makes a YUYV image of its size, line points found in it are finite and goal posts inside it.
pub fn frame(bytes: &[u8]) {
    let Some((header, payload)) = bytes.split_first_chunk::<HEADER_SIZE>() else { return };
    if let Ok(parsed) = FrameHeader::parse(header) {
        assert_eq!(FrameHeader::parse(&parsed.to_bytes()), Ok(parsed));
        let size = parsed.payload_size();
        let image = YuyvImage::new(parsed.width, parsed.height, payload.to_vec());
        assert_eq!(image.is_ok(), payload.len() == size, "payload {} for a header of {size}", payload.len());
        // Whatever the pixels, line points are finite and on the ground in front of the camera.
        if let Ok(image) = image {
            let camera = parsed.camera.unwrap_or_default();
            let frame = Frame::Yuyv(image);
            let found = detect(&frame, &CameraIntrinsics::nao_top(), &camera, &FieldDimensions::default())
                .expect("a valid frame can be searched");
            for point in &found.points {
                assert!(point.ground.x.is_finite() && point.ground.y.is_finite(), "{point:?}");
            }
            // Goal posts are finite and lie inside the frame.
            let (width, height) = frame.dimensions();
            for post in &found.posts {
                let foot = post.sighting.foot;
                assert!(post.bearing().is_finite(), "{post:?}");
                assert!(
                    foot.x >= 0.0 && foot.x <= f64::from(width) && foot.y <= f64::from(height),
                    "{post:?}"
                );
            }
        }
    }
}

/// An ONNX model file with its contract: loads or errs, never panics; a loaded model's contract
/// reads back from its own JSON.
pub fn model(bytes: &[u8]) {
    if let Ok(model) = Model::from_bytes(bytes, "fuzz") {
        let json = serde_json::to_string(model.contract()).expect("a contract serialises");
        assert!(ModelContract::from_json(&json).is_ok());
    }
}

/// A line of a recording's `frames.jsonl`: parses and validates, or errs.
pub fn recording(bytes: &[u8]) {
    if let Ok(line) = std::str::from_utf8(bytes) {
        let _ = FrameRecord::parse_line(line);
    }
}

/// A TOML config file: parses or errs, and validation of what parsed never panics.
pub fn config(bytes: &[u8]) {
    if let Ok(text) = std::str::from_utf8(bytes) {
        if let Ok(config) = Config::parse(text, Path::new("fuzz.toml")) {
            let _ = config.validate();
        }
    }
}
