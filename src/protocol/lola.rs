//! LoLA sensor messages: the part of the state map (msgpack, 83 Hz) that fall and pick-up detection and
//! the camera pose read.

use serde::Deserialize;
use thiserror::Error;

use crate::geometry::BodyAngles;

/// The part of a LoLA state message (msgpack map, 83 Hz) relocd reads; other keys are ignored.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct LolaState {
    /// Torso angles about x (roll) and y (pitch), radians.
    #[serde(rename = "Angles")]
    pub angles: [f32; 2],
    /// Angular velocity about x, y, z, rad/s.
    #[serde(rename = "Gyroscope")]
    pub gyroscope: [f32; 3],
    /// Foot pressure, kg: left foot front-left, front-right, rear-left, rear-right, then the right foot.
    #[serde(rename = "FSR")]
    pub fsr: [f32; 8],
    /// Joint angles in LoLA's order (HeadYaw, HeadPitch, then arms and legs), radians; empty when the
    /// sender leaves them out.
    #[serde(rename = "Position", default)]
    pub position: Vec<f32>,
}

/// Why bytes are not a LoLA state message.
#[derive(Debug, Error)]
#[error("sensor message is not a LoLA state map with Angles[2], Gyroscope[3] and FSR[8]: {0}")]
pub struct SensorError(#[from] rmp_serde::decode::Error);

impl LolaState {
    /// Decodes one msgpack message.
    pub fn from_msgpack(bytes: &[u8]) -> Result<Self, SensorError> {
        Ok(rmp_serde::from_slice(bytes)?)
    }

    /// The body angles that turn the camera, when the message carries the head joints.
    pub fn body_angles(&self) -> Option<BodyAngles> {
        let (&head_yaw, &head_pitch) = (self.position.first()?, self.position.get(1)?);
        Some(BodyAngles {
            torso_roll: self.angles[0].into(),
            torso_pitch: self.angles[1].into(),
            head_yaw: head_yaw.into(),
            head_pitch: head_pitch.into(),
        })
    }
}

/// Length of the first whole msgpack value in a stream of `bytes` (LoLA's socket), if one is complete. Malformed bytes count as
/// a one-byte value, so the caller's decoder refuses them and the stream moves on.
pub fn next_msgpack_value(bytes: &[u8]) -> Option<usize> {
    if bytes.is_empty() {
        return None;
    }
    let mut rest = bytes;
    match rmp_serde::from_read::<_, serde::de::IgnoredAny>(&mut rest) {
        Ok(_) => Some(bytes.len() - rest.len()),
        Err(
            rmp_serde::decode::Error::InvalidMarkerRead(error)
            | rmp_serde::decode::Error::InvalidDataRead(error),
        ) if error.kind() == std::io::ErrorKind::UnexpectedEof => None,
        Err(_) => Some(1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn msgpack_values_are_found_whole_in_a_stream() {
        let state = serde_json::json!({"Angles": [0.0, 0.1], "Gyroscope": [0, 0, 0], "FSR": [1, 1, 1, 1, 1, 1, 1, 1]});
        let one = rmp_serde::to_vec_named(&state).unwrap();
        let two = [one.clone(), one.clone()].concat();
        assert_eq!(next_msgpack_value(&two), Some(one.len()));
        assert_eq!(next_msgpack_value(&one[..one.len() - 3]), None, "wait for the rest");
        assert_eq!(next_msgpack_value(b"\xc1rest"), Some(1), "0xc1 is never valid: skip it");
        assert_eq!(next_msgpack_value(b""), None);
    }

    #[test]
    fn lola_messages_decode_and_garbage_is_an_error() {
        #[derive(serde::Serialize)]
        struct Message {
            #[serde(rename = "Angles")]
            angles: [f32; 2],
            #[serde(rename = "Gyroscope")]
            gyroscope: [f32; 3],
            #[serde(rename = "FSR")]
            fsr: [f32; 8],
            #[serde(rename = "Battery")]
            battery: [f32; 4],
        }
        let message = Message { angles: [0.1, 0.2], gyroscope: [0.0; 3], fsr: [0.5; 8], battery: [1.0; 4] };
        let bytes = rmp_serde::to_vec_named(&message).unwrap();
        let state = LolaState::from_msgpack(&bytes).unwrap();
        assert_eq!(state.angles, [0.1, 0.2]);
        assert_eq!(state.fsr, [0.5; 8]);
        assert_eq!(state.body_angles(), None, "no joint positions, no head angles");
        assert!(LolaState::from_msgpack(&bytes[..bytes.len() / 2]).is_err());
        assert!(LolaState::from_msgpack(b"\xc1garbage").is_err());
        let short =
            rmp_serde::to_vec_named(&serde_json::json!({"Angles": [0.1], "Gyroscope": [0, 0, 0]})).unwrap();
        let error = LolaState::from_msgpack(&short).unwrap_err().to_string();
        assert!(error.contains("LoLA state"), "{error}");
    }

    #[test]
    fn the_head_joints_and_the_torso_angles_give_the_body_angles() {
        let mut position = vec![0.0f32; 25];
        position[..2].copy_from_slice(&[0.5, -0.25]);
        let message = serde_json::json!({"Angles": [0.125, 0.0625], "Gyroscope": [0, 0, 0], "FSR": vec![1.0; 8],
            "Position": position});
        let state = LolaState::from_msgpack(&rmp_serde::to_vec_named(&message).unwrap()).unwrap();
        let body = BodyAngles { torso_roll: 0.125, torso_pitch: 0.0625, head_yaw: 0.5, head_pitch: -0.25 };
        assert_eq!(state.body_angles(), Some(body));
        let one_joint = serde_json::json!({"Angles": [0, 0], "Gyroscope": [0, 0, 0], "FSR": vec![1.0; 8], "Position": [0.5]});
        let state = LolaState::from_msgpack(&rmp_serde::to_vec_named(&one_joint).unwrap()).unwrap();
        assert_eq!(state.body_angles(), None);
    }
}
