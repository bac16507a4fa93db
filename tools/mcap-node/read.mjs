#!/usr/bin/env node
// Dump an MCAP bag as JSON with @mcap/core (an MCAP reader independent of the Python one), for
// cross-checks of the bags written by hexapod_sim.bagio.
//
//   node tools/mcap-node/read.mjs BAG [--stream]
//
// BAG: a rosbag2 directory (its *.mcap files are read in name order) or a single .mcap file.
// Default: McapIndexedReader (uses the summary/index: checks that a closed bag's index is valid).
// --stream: McapStreamReader over the whole file (no index needed).
// Output (stdout, one JSON document): {files, header, schemas, channels, metadata, messages}
// with messages = [{topic, schema, logTime, publishTime, sequence, data}] in log-time order
// (indexed) or file order (stream); times are decimal strings of nanoseconds, data is the CDR
// payload in base64. Zstd chunks are decompressed with the `fzstd` package when installed, else
// with the `zstd` command-line tool; lz4 chunks need the `lz4js` package.
// Exit status: 0 ok, 2 usage / unreadable input (message on stderr).
import { execFileSync } from "node:child_process";
import { openSync, readSync, closeSync, fstatSync, readFileSync, readdirSync, statSync } from "node:fs";
import { join } from "node:path";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";

function die(msg) {
  process.stderr.write(`read.mjs: ${msg}\n`);
  process.exit(2);
}

async function optionalImport(name) {
  try {
    return await import(name);
  } catch {
    return undefined;
  }
}

async function decompressHandlers() {
  const fzstd = await optionalImport("fzstd");
  const lz4js = await optionalImport("lz4js");
  return {
    zstd: (buffer, size) => {
      if (fzstd) return fzstd.decompress(buffer, new Uint8Array(Number(size)));
      try {
        return new Uint8Array(execFileSync("zstd", ["-d", "-c", "-q"], { input: buffer, maxBuffer: Number(size) + 1024 }));
      } catch (err) {
        throw new Error(`zstd chunk: neither the fzstd package nor a working zstd command is available (${err.message})`);
      }
    },
    lz4: (buffer, size) => {
      if (!lz4js) throw new Error("lz4 chunk: the lz4js package is not installed");
      return Uint8Array.from(lz4js.decompress(buffer, Number(size)));
    },
  };
}

function bagFiles(path) {
  let st;
  try {
    st = statSync(path);
  } catch {
    die(`${path}: no such file or directory`);
  }
  if (st.isFile()) return [path];
  const files = readdirSync(path).filter((f) => f.endsWith(".mcap")).sort().map((f) => join(path, f));
  if (files.length === 0) die(`${path}: directory contains no .mcap file`);
  return files;
}

class FileReadable {
  constructor(path) {
    this.fd = openSync(path, "r");
    this.bytes = BigInt(fstatSync(this.fd).size);
  }
  async size() {
    return this.bytes;
  }
  async read(offset, length) {
    const buf = new Uint8Array(Number(length));
    readSync(this.fd, buf, 0, buf.length, Number(offset));
    return buf;
  }
  close() {
    closeSync(this.fd);
  }
}

const b64 = (u8) => Buffer.from(u8.buffer, u8.byteOffset, u8.byteLength).toString("base64");
const text = (u8) => new TextDecoder().decode(u8);
const mapObj = (m) => Object.fromEntries(m instanceof Map ? m : Object.entries(m ?? {}));

async function readIndexed(file, handlers, out) {
  const readable = new FileReadable(file);
  try {
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: handlers });
    out.header.push({ file, profile: reader.header.profile, library: reader.header.library });
    for (const s of reader.schemasById.values()) {
      out.schemas.push({ file, id: s.id, name: s.name, encoding: s.encoding, data: text(s.data) });
    }
    for (const c of reader.channelsById.values()) {
      out.channels.push({ file, id: c.id, topic: c.topic, messageEncoding: c.messageEncoding, schemaId: c.schemaId, metadata: mapObj(c.metadata) });
    }
    for await (const m of reader.readMetadata()) {
      out.metadata.push({ file, name: m.name, metadata: mapObj(m.metadata) });
    }
    for await (const m of reader.readMessages()) {
      const ch = reader.channelsById.get(m.channelId);
      const schema = reader.schemasById.get(ch.schemaId);
      out.messages.push({ topic: ch.topic, schema: schema?.name ?? "", logTime: m.logTime.toString(), publishTime: m.publishTime.toString(), sequence: m.sequence, data: b64(m.data) });
    }
    out.statistics.push({ file, messageCount: reader.statistics?.messageCount?.toString() ?? null, chunkCount: reader.chunkIndexes.length });
  } finally {
    readable.close();
  }
}

function readStream(file, handlers, out) {
  const reader = new McapStreamReader({ decompressHandlers: handlers, validateCrcs: true });
  reader.append(new Uint8Array(readFileSync(file)));
  const channels = new Map();
  const schemas = new Map();
  for (let rec; (rec = reader.nextRecord()); ) {
    switch (rec.type) {
      case "Header":
        out.header.push({ file, profile: rec.profile, library: rec.library });
        break;
      case "Schema":
        if (!schemas.has(rec.id)) {
          schemas.set(rec.id, rec);
          out.schemas.push({ file, id: rec.id, name: rec.name, encoding: rec.encoding, data: text(rec.data) });
        }
        break;
      case "Channel":
        if (!channels.has(rec.id)) {
          channels.set(rec.id, rec);
          out.channels.push({ file, id: rec.id, topic: rec.topic, messageEncoding: rec.messageEncoding, schemaId: rec.schemaId, metadata: mapObj(rec.metadata) });
        }
        break;
      case "Metadata":
        out.metadata.push({ file, name: rec.name, metadata: mapObj(rec.metadata) });
        break;
      case "Message": {
        const ch = channels.get(rec.channelId);
        out.messages.push({ topic: ch?.topic ?? "", schema: schemas.get(ch?.schemaId)?.name ?? "", logTime: rec.logTime.toString(), publishTime: rec.publishTime.toString(), sequence: rec.sequence, data: b64(rec.data) });
        break;
      }
      default:
        break;
    }
  }
  out.complete.push({ file, done: reader.done(), unparsedBytes: reader.bytesRemaining() });
}

async function main() {
  const args = process.argv.slice(2);
  const stream = args.includes("--stream");
  const paths = args.filter((a) => !a.startsWith("--"));
  if (paths.length !== 1) die("usage: node read.mjs BAG [--stream]");
  const handlers = await decompressHandlers();
  const files = bagFiles(paths[0]);
  const out = { files, mode: stream ? "stream" : "indexed", header: [], schemas: [], channels: [], metadata: [], messages: [], statistics: [], complete: [] };
  for (const file of files) {
    try {
      if (stream) readStream(file, handlers, out);
      else await readIndexed(file, handlers, out);
    } catch (err) {
      die(`${file}: ${err.message}`);
    }
  }
  process.stdout.write(JSON.stringify(out) + "\n");
}

await main();
