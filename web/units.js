// SI prefixes: formatting numbers for readouts and axes, and reading what a user types
// ("116.1 GPa", "20 nm", "500 us", "1e-4 s") into a value in the node's unit.

const PREFIX = { y: -24, z: -21, a: -18, f: -15, p: -12, n: -9, "µ": -6, "μ": -6, u: -6, m: -3, "": 0, k: 3, M: 6, G: 9, T: 12, P: 15, E: 18 };
const SYMBOL = { "-24": "y", "-21": "z", "-18": "a", "-15": "f", "-12": "p", "-9": "n", "-6": "µ", "-3": "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T", 15: "P", 18: "E" };

/** Whether a unit takes SI prefixes ("1" is dimensionless, "" is text or boolean). */
export function prefixable(unit) {
  // "1/s" would read "1.2 k1/s": reciprocal units are shown without a prefix
  return !!unit && unit !== "1" && unit !== "bit" && unit !== "samples" && unit !== "pixels" && unit !== "frames" && unit !== "clients" && unit !== "messages" && unit !== "K" && unit !== "°" && unit !== "%" && !unit.startsWith("1/");
}

/** The exponent (a multiple of 3, -24 … 18) of the prefix that shows `x` as 1 … 999. */
export function prefixExponent(x, digits = 4) {
  const a = Math.abs(x);
  if (!isFinite(a) || a === 0) return 0;
  let e = Math.floor(Math.log10(a) / 3) * 3;
  // 999.96e-9 rounds to "1000 n" at 4 digits: move up when rounding would reach 1000.
  if (Number((a / 10 ** e).toPrecision(digits)) >= 1000) e += 3;
  return Math.max(-24, Math.min(18, e));
}

export function prefixSymbol(exponent) {
  return SYMBOL[exponent] ?? "";
}

function unitSuffix(unit) {
  return unit === "1" || !unit ? "" : unit;
}

/**
 * A readout: `digits` significant digits with an SI prefix, e.g. si(1.93e-8, "m") = "19.30 nm".
 * Fixed digits keep live numbers from changing width.
 */
export function si(value, unit, digits = 4) {
  if (value === null || value === undefined || Number.isNaN(value)) return "–";
  if (!isFinite(value)) return value > 0 ? "∞" : "−∞";
  const u = unitSuffix(unit);
  if (!prefixable(unit)) return `${fmtNumber(value, digits)}${u ? " " + u : ""}`;
  const e = prefixExponent(value, digits);
  const mant = value / 10 ** e;
  return `${mant.toPrecision(digits).replace("-", "−")} ${prefixSymbol(e)}${u}`;
}

/** Like `si` but trailing zeros dropped: for values a user typed or will edit ("116.1 GPa", "20 nm"). */
export function siShort(value, unit, digits = 7) {
  if (typeof value !== "number") return String(value);
  if (!isFinite(value)) return String(value);
  const u = unitSuffix(unit);
  if (!prefixable(unit)) {
    const s = Number.isInteger(value) ? String(value) : trim(value.toPrecision(digits));
    return u ? `${s} ${u}` : s;
  }
  const e = prefixExponent(value, digits);
  // toPrecision rounds away the last-bit noise of the scaling (116.1e9 shows as 116.1).
  const mant = e < 0 ? value * 10 ** -e : value / 10 ** e;
  return `${trim(mant.toPrecision(digits))} ${prefixSymbol(e)}${u}`;
}

function trim(s) {
  if (s.includes("e")) {
    const [m, x] = s.split("e");
    return `${trim(m)}e${x}`;
  }
  return s.includes(".") ? s.replace(/0+$/, "").replace(/\.$/, "") : s;
}

function fmtNumber(v, digits) {
  if (Number.isInteger(v) && Math.abs(v) < 1e15) return String(v);
  const a = Math.abs(v);
  if (a !== 0 && (a < 1e-3 || a >= 1e6)) return v.toExponential(digits - 1);
  return v.toPrecision(digits);
}

/**
 * Reads what the user typed, in the node's unit: a number, an optional SI prefix, and
 * optionally the unit itself ("60 GPa", "60G", "6e10", "6e10 Pa", "20nm", "500 us").
 * Returns the number, or throws an Error saying what could not be read.
 */
export function parseSI(text, unit) {
  const s = String(text).trim().replace(/\u2212/g, "-");
  const m = /^([+-]?)(\d+(?:\.\d*)?|\.\d+)(?:[eE]([+-]?\d+))?\s*(.*)$/.exec(s);
  if (!m) throw new Error(`cannot read “${text}” as a number: write e.g. ${example(unit)}`);
  let rest = m[4].trim();
  const u = unitSuffix(unit);
  if (u && rest.endsWith(u)) rest = rest.slice(0, rest.length - u.length).trim();
  else if (u && rest.toLowerCase().endsWith(u.toLowerCase()) && rest.length > u.length) rest = rest.slice(0, rest.length - u.length).trim();
  if (!(rest in PREFIX)) {
    throw new Error(`cannot read the unit “${m[4].trim()}” of “${text}”: this value is in ${u || "plain numbers"}; write e.g. ${example(unit)}`);
  }
  const exp = (m[3] ? parseInt(m[3], 10) : 0) + PREFIX[rest];
  // Build the decimal string so that "116.1 G" gives exactly the double of 116.1e9.
  return Number(`${m[1]}${m[2]}e${exp}`);
}

function example(unit) {
  switch (unit) {
    case "Pa": return "“116.1 GPa”";
    case "m": return "“20 nm”";
    case "Hz": return "“100 kHz”";
    case "s": return "“500 µs” or “0.5 ms”";
    default: return "“42”";
  }
}

/** A bound of a range: 0 plain, others with their prefix and unit ("0", "1 mHz", "10 TPa"). */
function bound(value, unit) {
  return value === 0 || !prefixable(unit) ? siShort(value, "1", 4) : siShort(value, unit, 4);
}

/**
 * A node's allowed range as the daemon enforces it, each end open or closed: "0 < E ≤ 10 TPa",
 * "8 ≤ x ≤ 1024 pixels". `symbol` stands for the value; "" when there is no range.
 */
export function rangeText({ min, max, min_inclusive: lo = true, max_inclusive: hi = true, unit }, symbol = "x") {
  if (typeof min !== "number" || typeof max !== "number") return "";
  return `${bound(min, unit)} ${lo ? "≤" : "<"} ${symbol} ${hi ? "≤" : "<"} ${siShort(max, unit, 4)}`;
}

const NUM = String.raw`[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:e[+-]?\d+)?`;

/**
 * A daemon's refusal in the node's units: the plain numbers it writes for the value and its
 * range ("/sample/youngs_modulus = -5e9 is out of range: allowed 0 < value ≤ 1e13 Pa", a
 * sweep's "/sweeper/start = -5e9 is outside the range of … now: allowed 0 < value ≤ 1e13 Pa")
 * with SI prefixes ("= -5 GPa …: allowed 0 < value ≤ 10 TPa"; the older "allowed 0 … 1e13"
 * form too). Other text
 * is kept as is.
 */
export function inUserUnits(message, unit) {
  if (!prefixable(unit)) return message;
  const u = unitSuffix(unit).replace(/[.*+?^${}()|[\]\\/]/g, "\\$&");
  // A number as the daemon writes it: plain, or with a prefixed unit ("102.04 kHz").
  const q = `(${NUM})(?: (${PREFIXES})?${u})?`;
  const value = (n, prefix) => Number(n) * (prefix ? PREFIX_SCALE[prefix] : 1);
  return String(message)
    .replace(new RegExp(`allowed ${q} (<|≤) value (<|≤) ${q}`),
      (_, lo, lp, a, b, hi, hp) =>
        `allowed ${bound(value(lo, lp), unit)} ${a} value ${b} ${siShort(value(hi, hp), unit, 4)}`)
    .replace(new RegExp(`allowed ${q} … ${q}`),
      (_, lo, lp, hi, hp) => `allowed ${bound(value(lo, lp), unit)} … ${siShort(value(hi, hp), unit, 4)}`)
    .replace(new RegExp(`( = )${q}(?= is |: |$)`, "g"),
      (_, eq, v, vp) => `${eq}${siShort(value(v, vp), unit, 4)}`);
}

/** The SI prefixes a daemon's quantity may carry, and their scales. */
const PREFIX_SCALE = {
  f: 1e-15, p: 1e-12, n: 1e-9, "µ": 1e-6, u: 1e-6, m: 1e-3, k: 1e3, M: 1e6, G: 1e9, T: 1e12,
};
const PREFIXES = Object.keys(PREFIX_SCALE).join("|");

/**
 * A refusal of a `set` in the user's units: the unit of the node it names first
 * ("/x/y = …"), as `unitOf(path)` gives it, applied by `inUserUnits`.
 */
export function refusalInUserUnits(message, unitOf) {
  const path = /^(\/[\w/]+) = /.exec(String(message))?.[1];
  return path ? inUserUnits(message, unitOf(path) ?? "") : String(message);
}

/** Latency in ns → "0.63 ms" / "850 µs". */
export function ns(value) {
  return value == null ? "–" : si(value * 1e-9, "s", 3);
}

/** Pretty linear ticks ("nice numbers") between lo and hi, about `n` of them. */
export function niceTicks(lo, hi, n = 5) {
  if (!(hi > lo)) return { ticks: [lo], step: 1 };
  const raw = (hi - lo) / Math.max(1, n);
  const mag = 10 ** Math.floor(Math.log10(raw));
  const f = raw / mag;
  const step = (f < 1.5 ? 1 : f < 3 ? 2 : f < 7 ? 5 : 10) * mag;
  const ticks = [];
  const first = Math.ceil(lo / step - 1e-9);
  for (let k = first; k * step <= hi + step * 1e-9; k++) ticks.push(k === 0 ? 0 : Number((k * step).toPrecision(12)));
  return { ticks, step };
}
