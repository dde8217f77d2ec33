// Independent check of an rtsid recording with the TypeScript MCAP library (@mcap/core, the
// reader Foxglove builds on): open it with the indexed reader and count messages per topic.
// Usage: NODE_PATH=<dir with node_modules> node mcap_check.js FILE.mcap  -> JSON on stdout
const fs = require("fs");
const { McapIndexedReader } = require("@mcap/core");
const zstd = require("@foxglove/wasm-zstd");

async function main(path) {
  await zstd.isLoaded;
  const fd = fs.openSync(path, "r");
  const size = BigInt(fs.fstatSync(fd).size);
  const readable = {
    size: async () => size,
    read: async (offset, length) => {
      const buf = Buffer.alloc(Number(length));
      fs.readSync(fd, buf, 0, Number(length), Number(offset));
      return new Uint8Array(buf.buffer, buf.byteOffset, buf.length);
    },
  };
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: { zstd: (data, size) => zstd.decompress(data, Number(size)) },
  });
  const counts = {};
  const encodings = {};
  let firstEstimate = null;
  for await (const msg of reader.readMessages()) {
    const channel = reader.channelsById.get(msg.channelId);
    const schema = reader.schemasById.get(channel.schemaId);
    counts[channel.topic] = (counts[channel.topic] || 0) + 1;
    encodings[channel.topic] = [schema.encoding, channel.messageEncoding];
    if (channel.topic === "/estimate" && firstEstimate === null) {
      firstEstimate = JSON.parse(new TextDecoder().decode(msg.data));
    }
  }
  fs.closeSync(fd);
  console.log(JSON.stringify({ counts, encodings, firstEstimate }));
}

main(process.argv[2]).catch((err) => {
  console.error(String(err));
  process.exit(1);
});
