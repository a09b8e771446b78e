// Read MCAP files with Foxglove's TypeScript reader (@mcap/core's McapIndexedReader, the one the
// Foxglove app uses for local files): open the summary, read every message through the chunk and
// message indexes with CRC validation, and print per file the message count per topic and the
// schema encodings. Exit code 1 if any file fails. Run by tools/check_mcap_ts.sh.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";

const decompressHandlers = await loadDecompressHandlers();
let failed = 0;
for (const path of process.argv.slice(2)) {
  const fh = await open(path, "r");
  const size = (await fh.stat()).size;
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buf = new Uint8Array(Number(length));
      await fh.read(buf, 0, Number(length), Number(offset));
      return buf;
    },
  };
  try {
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    const topics = new Map();
    const encodings = new Set();
    for (const ch of reader.channelsById.values()) {
      const s = reader.schemasById.get(ch.schemaId);
      encodings.add(`${ch.messageEncoding}/${s ? s.encoding : "-"}`);
    }
    let n = 0;
    let last = -1n;
    for await (const m of reader.readMessages({ validateCrcs: true })) {
      if (m.logTime < last) throw new Error("messages out of log-time order");
      last = m.logTime;
      const topic = reader.channelsById.get(m.channelId).topic;
      topics.set(topic, (topics.get(topic) ?? 0) + 1);
      n++;
    }
    const st = reader.statistics;
    if (st && BigInt(n) !== st.messageCount) throw new Error(`read ${n} messages, statistics say ${st.messageCount}`);
    const per = [...topics.entries()].sort().map(([t, k]) => `${t} ${k}`).join(", ");
    console.log(`OK   ${path}: ${n} messages in ${reader.chunkIndexes.length} chunks ` +
                `(${[...encodings].sort().join(" ")}); ${per}`);
  } catch (e) {
    failed++;
    console.log(`FAIL ${path}: ${e.message ?? e}`);
  } finally {
    await fh.close();
  }
}
process.exit(failed ? 1 : 0);
