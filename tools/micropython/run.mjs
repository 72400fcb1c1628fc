// Run a Python script under MicroPython (WebAssembly port) with the firmware importable.
//
//   node tools/micropython/run.mjs [--heapsize BYTES[k|m]] [--copy HOST=TARGET]... SCRIPT.py
//
// Loads @micropython/micropython-webassembly-pyscript (pinned in package.json /
// package-lock.json next to this file; install with `npm ci --prefix tools/micropython`),
// copies the --copy files into the in-memory filesystem, puts /lib on sys.path, runs
// SCRIPT.py as __main__ and prints its output.  Exit status: 0 when the script finished, 1
// when it raised (the traceback goes to stderr), 2 for a usage error.
//
// --copy HOST=TARGET (repeatable) copies the host file HOST (a path relative to the current
// directory, or absolute) to the absolute path TARGET of the in-memory filesystem, creating
// its folders: the MCU image (lodestar.regress.micropython.mcu_image lists it: modules under
// /lib/lodestar/), star databases and recorded packets.
//
// --heapsize sets the initial MicroPython heap (default 1 MiB).  It is not a cap: this
// build (the "pyscript" variant, MICROPY_GC_SPLIT_HEAP_AUTO) adds heap areas on demand up
// to the WebAssembly memory limit, so a script never gets MemoryError from a small
// --heapsize; measure heap use with gc.mem_alloc() instead.
//
// A line that is exactly `#@split` cuts the script into parts run one after another by
// separate mp.runPython calls sharing __main__'s globals.  This port never collects during
// a call: gc.collect() (like the automatic trigger) only requests a collection, which runs
// at the start of the next mp.runPython call, where no object hides in WebAssembly locals.
// So a script that measures live memory ends a part with gc.collect() and reads
// gc.mem_alloc() at the start of the next part.
//
// A script that leaves a generator in the global STEPS (a module's loop, as
// lodestar.regress.loop.replay) is then resumed once per mp.runPython call until it ends:
// each `yield` ends a part as `#@split` does, so the loop's gc.collect() before a yield has
// run when it resumes.

import fs from "node:fs";
import path from "node:path";

import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";

function usage(message) {
  process.stderr.write(`run.mjs: ${message}\n` +
    "usage: node tools/micropython/run.mjs [--heapsize BYTES[k|m]] [--copy HOST=TARGET]... " +
    "SCRIPT.py\n");
  process.exit(2);
}

function parseSize(text) {
  const match = /^(\d+)([kKmM]?)$/.exec(text);
  if (!match) usage(`bad heap size ${JSON.stringify(text)}`);
  const scale = { "": 1, k: 1024, m: 1024 * 1024 }[match[2].toLowerCase()];
  return Number(match[1]) * scale;
}

function parseCopy(text) {
  const at = text.indexOf("=");
  if (at <= 0 || !text.slice(at + 1).startsWith("/")) {
    usage(`bad --copy ${JSON.stringify(text)}: expected HOST=/ABSOLUTE/TARGET`);
  }
  const host = text.slice(0, at);
  if (!fs.existsSync(host) || !fs.statSync(host).isFile()) usage(`--copy: no file ${host}`);
  return [host, text.slice(at + 1)];
}

let heapsize = 1024 * 1024;
let script = null;
const copies = [];
const args = process.argv.slice(2);
for (let i = 0; i < args.length; i++) {
  if (args[i] === "--heapsize" && i + 1 < args.length) {
    heapsize = parseSize(args[++i]);
  } else if (args[i] === "--copy" && i + 1 < args.length) {
    copies.push(parseCopy(args[++i]));
  } else if (script === null) {
    script = args[i];
  } else {
    usage(`unexpected argument ${JSON.stringify(args[i])}`);
  }
}
if (script === null) usage("no script given");

const code = fs.readFileSync(script, "utf8");
const stdout = (line) => process.stdout.write(line + "\n");
const stderr = (line) => process.stderr.write(line + "\n");
const mp = await loadMicroPython({ heapsize, stdout, stderr, linebuffer: true });

for (const [host, target] of copies) {
  mp.FS.mkdirTree(path.posix.dirname(target));
  mp.FS.writeFile(target, fs.readFileSync(host));
}

let status = 0;
try {
  mp.runPython("import sys\nif '/lib' not in sys.path:\n    sys.path.insert(0, '/lib')\n" +
               "STEPS = None\n");
  for (const part of code.split(/^#@split[ \t]*$/m)) mp.runPython(part);
  const step = "try:\n    next(STEPS)\nexcept StopIteration:\n    STEPS = None\n";
  while (mp.globals.get("STEPS") !== null) mp.runPython(step);
} catch (error) {
  if (error && error.name === "PythonError") {
    // error.message is the MicroPython traceback.
    process.stderr.write(String(error.message).replace(/\n?$/, "\n"));
    status = 1;
  } else {
    throw error;
  }
}
// Flush a last line the script printed without a newline (linebuffer holds it).
const mod = mp._module;
if (mod && mod._stdoutBuffer && mod._stdoutBuffer.length) {
  process.stdout.write(mod._textDecoder.decode(new Uint8Array(mod._stdoutBuffer)) + "\n");
}
process.exitCode = status;
