//! gRPC calls with message bytes written by hand, for what a generated client would not send:
//! malformed protobuf, messages that cost far more decoded than sent.

use prost::bytes::{Buf, BufMut};
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::transport::Channel;
use tonic::{Response, Status};

/// A codec that sends bytes as they are and reads an answer's bytes without decoding them.
#[derive(Debug, Clone, Copy, Default)]
pub struct RawCodec;

/// The encoder and decoder of [`RawCodec`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Raw;

impl Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = Raw;
    type Decoder = Raw;

    fn encoder(&mut self) -> Raw {
        Raw
    }

    fn decoder(&mut self) -> Raw {
        Raw
    }
}

impl Encoder for Raw {
    type Item = Vec<u8>;
    type Error = Status;

    fn encode(&mut self, item: Vec<u8>, buf: &mut EncodeBuf<'_>) -> Result<(), Status> {
        buf.put_slice(&item);
        Ok(())
    }
}

impl Decoder for Raw {
    type Item = Vec<u8>;
    type Error = Status;

    fn decode(&mut self, buf: &mut DecodeBuf<'_>) -> Result<Option<Vec<u8>>, Status> {
        let mut out = vec![0; buf.remaining()];
        buf.copy_to_slice(&mut out);
        Ok(Some(out))
    }
}

/// A unary call of `facepose.v1.PoseService/<rpc>` with `message` as its request bytes; no
/// client-side size limit.
pub async fn unary(
    channel: Channel,
    rpc: &str,
    message: Vec<u8>,
) -> Result<Response<Vec<u8>>, Status> {
    let (mut grpc, path) = ready(channel, rpc).await?;
    grpc.unary(tonic::Request::new(message), path, RawCodec)
        .await
}

/// A bidirectional call of `facepose.v1.PoseService/<rpc>` that sends `messages` as they are,
/// then the first answer: a message's bytes, `None` at the end of the stream, or the status
/// that ended it.
pub async fn first_answer(
    channel: Channel,
    rpc: &str,
    messages: Vec<Vec<u8>>,
) -> Result<Option<Vec<u8>>, Status> {
    let (mut grpc, path) = ready(channel, rpc).await?;
    let request = tonic::Request::new(tokio_stream::iter(messages));
    let mut answers = grpc.streaming(request, path, RawCodec).await?.into_inner();
    answers.message().await
}

/// A client on `channel` with no size limits, ready, and the path of `rpc`.
async fn ready(
    channel: Channel,
    rpc: &str,
) -> Result<
    (
        tonic::client::Grpc<Channel>,
        tonic::codegen::http::uri::PathAndQuery,
    ),
    Status,
> {
    let mut grpc = tonic::client::Grpc::new(channel)
        .max_encoding_message_size(usize::MAX)
        .max_decoding_message_size(usize::MAX);
    grpc.ready()
        .await
        .map_err(|e| Status::unavailable(e.to_string()))?;
    let path = format!("/facepose.v1.PoseService/{rpc}")
        .parse()
        .expect("a valid path");
    Ok((grpc, path))
}
