// Run a Python script under MicroPython (WebAssembly port) with the firmware importable.
//
//   node tools/micropython/run.mjs [--heapsize BYTES[k|m]] [--copy HOST=TARGET]... SCRIPT.py
//
// Loads @micropython/micropython-webassembly-pyscript (pinned in package.json /
// package-lock.json next to this file; install with `npm ci --prefix tools/micropython`),
// copies lodestar/__init__.py, lodestar/contract.py and the firmware package (every .py of
// firmware/ and of its subpackages) into the in-memory filesystem as /lib/lodestar/ and
// /lib/lodestar/firmware/, puts /lib on sys.path, runs SCRIPT.py as __main__ and prints its
// output.  Exit status: 0 when the script
// finished, 1 when it raised (the traceback goes to stderr), 2 for a usage error.
//
// --copy HOST=TARGET (repeatable) also copies the host file HOST (a path relative to the
// current directory, or absolute) to the absolute path TARGET of the in-memory filesystem,
// creating its folders: data files (a star database, recorded packets) or extra modules
// (TARGET under /lib/lodestar/ to import them as lodestar.NAME).
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

import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

import { loadMicroPython } from "@micropython/micropython-webassembly-pyscript";

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, "..", "..");

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

// The firmware package and the two lodestar files it imports.
function copy(source, target) {
  mp.FS.writeFile(target, fs.readFileSync(path.join(repo, source)));
}
mp.FS.mkdirTree("/lib/lodestar");
copy("lodestar/__init__.py", "/lib/lodestar/__init__.py");
copy("lodestar/contract.py", "/lib/lodestar/contract.py");
function copyPackage(source, target) {
  mp.FS.mkdirTree(target);
  for (const entry of fs.readdirSync(path.join(repo, source), { withFileTypes: true })) {
    const name = entry.name;
    if (entry.isDirectory() && fs.existsSync(path.join(repo, source, name, "__init__.py"))) {
      copyPackage(path.join(source, name), `${target}/${name}`);
    } else if (entry.isFile() && name.endsWith(".py")) {
      copy(path.join(source, name), `${target}/${name}`);
    }
  }
}
copyPackage("firmware", "/lib/lodestar/firmware");
// Extra files (--copy), after the firmware so that they may add modules next to it.
for (const [host, target] of copies) {
  mp.FS.mkdirTree(path.posix.dirname(target));
  mp.FS.writeFile(target, fs.readFileSync(host));
}

let status = 0;
try {
  mp.runPython("import sys\nif '/lib' not in sys.path:\n    sys.path.insert(0, '/lib')\n");
  for (const part of code.split(/^#@split[ \t]*$/m)) mp.runPython(part);
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
