// Job forms from the API's own OpenAPI document: which kinds exist, their params and inputs,
// and how each field's text is checked and turned into a JSON value. No DOM here.

function resolve(openapi, schema) {
  let s = schema || {};
  for (let i = 0; i < 5 && s.$ref; i += 1) {
    s = openapi.components.schemas[s.$ref.split("/").pop()];
  }
  if (s.allOf && s.allOf.length === 1) return resolve(openapi, s.allOf[0]);
  return s;
}

/** [{kind, title, params, inputs}] from every `*JobCreate` schema with a `kind` constant. */
export function kindsOf(openapi) {
  const kinds = [];
  for (const [name, schema] of Object.entries(openapi.components?.schemas || {})) {
    const kind = schema.properties?.kind;
    if (!name.endsWith("JobCreate") || !kind) continue;
    const value = kind.const ?? kind.enum?.[0];
    if (!value) continue;
    kinds.push({
      kind: value, title: schema.description || value,
      params: resolve(openapi, schema.properties.params),
      inputs: resolve(openapi, schema.properties.inputs),
    });
  }
  return kinds;
}

function humanize(name, schema) {
  return schema.title || name.replace(/_/g, " ");
}

/** A field descriptor for one property of a params (or inputs) schema. */
export function fieldOf(openapi, name, property) {
  const alternatives = (property.anyOf || [property]).map((s) => resolve(openapi, s));
  const nullable = alternatives.some((s) => s.type === "null");
  const main = alternatives.filter((s) => s.type !== "null");
  const first = main[0] || {};
  const field = {
    name, label: humanize(name, property), description: property.description || "",
    default: property.default ?? null, nullable, required: false,
  };
  const enums = main.flatMap((s) => s.enum || []);
  if (first.additionalProperties?.$ref?.endsWith("/JointOffsetIn")) {
    return { ...field, widget: "calibration" };
  }
  if (enums.length && main.some((s) => s.type === "object")) {
    return { ...field, widget: "json-or-enum", options: enums };
  }
  if (enums.length) return { ...field, widget: "select", options: enums };
  if (first.type === "boolean") return { ...field, widget: "select", options: [true, false] };
  if (first.type === "number" || first.type === "integer") {
    return { ...field, widget: "number", integer: first.type === "integer",
      minimum: first.minimum, exclusiveMinimum: first.exclusiveMinimum, maximum: first.maximum };
  }
  if (first.type === "array" && first.items?.enum) {
    return { ...field, widget: "list", options: first.items.enum };
  }
  if (first.type === "array" && first.prefixItems) {
    return { ...field, widget: "vector", size: first.prefixItems.length };
  }
  if (first.type === "object") {
    const values = resolve(openapi, first.additionalProperties);
    const types = (values.anyOf || [values]).map((s) => s.type).filter(Boolean);
    return { ...field, widget: "json", valueTypes: types };
  }
  return { ...field, widget: "text", minLength: first.minLength, maxLength: first.maxLength };
}

/** The field descriptors of a params schema, in its order. */
export function fieldsOf(openapi, schema) {
  return Object.entries(schema.properties || {}).map(([name, p]) => fieldOf(openapi, name, p));
}

function checkNumber(field, number) {
  if (!Number.isFinite(number)) return "expected a number";
  if (field.integer && !Number.isInteger(number)) return "expected a whole number";
  if (field.minimum !== undefined && number < field.minimum) return `expected ≥ ${field.minimum}`;
  if (field.exclusiveMinimum !== undefined && number <= field.exclusiveMinimum) {
    return `expected > ${field.exclusiveMinimum}`;
  }
  if (field.maximum !== undefined && number > field.maximum) return `expected ≤ ${field.maximum}`;
  return null;
}

function jsonTypeOf(value) {
  if (typeof value === "number") return Number.isInteger(value) ? "integer" : "number";
  return typeof value;
}

function checkObject(field, text) {
  let value;
  try { value = JSON.parse(text); } catch { return { error: 'expected JSON, e.g. {"1": "pelvis"}' }; }
  if (!value || typeof value !== "object" || Array.isArray(value)) {
    return { error: "expected a JSON object" };
  }
  const types = field.valueTypes || [];
  for (const [k, v] of Object.entries(value)) {
    const t = jsonTypeOf(v);
    const ok = !types.length || types.includes(t) || (t === "integer" && types.includes("number"));
    if (!ok) return { error: `${k}: expected ${types.join(" or ")}, got ${t}` };
  }
  return { value };
}

/** Turn a field's text into its JSON value: {value} (undefined: leave out) or {error}. */
export function parseField(field, text) {
  const raw = String(text ?? "").trim();
  if (raw === "") return { value: undefined };
  switch (field.widget) {
    case "select":
      if (field.options.map(String).includes(raw)) {
        return { value: field.options.find((o) => String(o) === raw) };
      }
      return { error: `expected one of ${field.options.join(", ")}` };
    case "number": {
      const number = Number(raw);
      const error = checkNumber(field, number);
      return error ? { error } : { value: number };
    }
    case "vector": {
      const parts = raw.split(/[\s,]+/).filter(Boolean).map(Number);
      if (parts.length !== field.size || parts.some((n) => !Number.isFinite(n))) {
        return { error: `expected ${field.size} numbers, e.g. 0, 1, 0` };
      }
      return { value: parts };
    }
    case "list": {
      const items = raw.split(/[\s,]+/).filter(Boolean);
      const bad = items.find((x) => !field.options.includes(x));
      return bad === undefined ? { value: items }
        : { error: `${bad}: expected some of ${field.options.join(", ")}` };
    }
    case "json":
      return checkObject(field, raw);
    case "json-or-enum":
      if (field.options.includes(raw)) return { value: raw };
      return raw.startsWith("{") ? checkObject(field, raw)
        : { error: `expected one of ${field.options.join(", ")} or a JSON object` };
    case "text":
      if (field.minLength !== undefined && raw.length < field.minLength) {
        return { error: `expected at least ${field.minLength} characters` };
      }
      if (field.maxLength !== undefined && raw.length > field.maxLength) {
        return { error: `expected at most ${field.maxLength} characters` };
      }
      return { value: raw };
    default:
      return { value: raw };
  }
}

/** Which kind a sniffed upload format belongs to (or "input" for extra recordings). */
export function kindForFormat(format) {
  if (["sensor-csv", "tracker", "npz"].includes(format)) return "skeleton";
  if (["kinematics-csv", "bvh", "mvnx"].includes(format)) return "translation";
  return "input";
}
