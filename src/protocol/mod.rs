//! Wire formats as pure encode/decode: each decoder validates every field and names what is wrong.

pub mod address;
pub mod control;
pub mod frame_header;
pub mod gamecontroller;
pub mod lola;
pub mod message;
