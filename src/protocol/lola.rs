//! LoLA sensor messages: the part of the state map (msgpack, 83 Hz) that fall and pick-up detection reads.

use serde::Deserialize;
use thiserror::Error;

/// The part of a LoLA state message (msgpack map, 83 Hz) the detector reads; other keys are ignored.
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(LolaState::from_msgpack(&bytes[..bytes.len() / 2]).is_err());
        assert!(LolaState::from_msgpack(b"\xc1garbage").is_err());
        let short =
            rmp_serde::to_vec_named(&serde_json::json!({"Angles": [0.1], "Gyroscope": [0, 0, 0]})).unwrap();
        let error = LolaState::from_msgpack(&short).unwrap_err().to_string();
        assert!(error.contains("LoLA state"), "{error}");
    }
}
