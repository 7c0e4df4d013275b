#!/usr/bin/env python3
"""Resolve Cura 4.13 machine settings into one flat definition file for the CuraEngine 4.13 CLI.

CuraEngine 4.13's `-j` loader only reads each setting's "default_value"; it ignores the "value"
formulas that the Cura GUI evaluates (and it rejects list-valued defaults). To get the settings Cura
itself would send for a Creality Ender-3, this script evaluates the Cura setting stack the way the GUI
does, for a single extruder:

    user overrides (USER below) > quality "standard" (base_global_standard + base_0.4_PLA_standard)
    > material generic_pla (fdm-materials) > variant 0.4mm Nozzle
    > definitions creality_ender3 > creality_base > fdmprinter (+ extruder creality_base_extruder_0 > fdmextruder)

and writes every setting as a string "default_value", with {setting} tokens in the start/end G-code
expanded as the GUI does.

Inputs: Debian packages cura 4.13.0-1 and fdm-materials 4.13.0-1 (installed, or just unpacked with
`apt-get download cura fdm-materials; dpkg-deb -x ...`).
Usage: cura_resolve_settings.py CURA_RESOURCES_DIR OUT.def.json
       (CURA_RESOURCES_DIR = .../usr/share/cura/resources, must also hold materials/generic_pla.xml.fdm_material)
"""
import ast, configparser, json, math, re, sys
import xml.etree.ElementTree as ET

START_GCODE_LIMITS = (  # creality_base's limit lines, values set to a stock Ender-3 (Marlin 2 defaults)
    "M201 X500.00 Y500.00 Z100.00 E5000.00 ;Setup machine max acceleration\n"
    "M203 X500.00 Y500.00 Z5.00 E25.00 ;Setup machine max feedrate\n"
    "M204 P500.00 R1000.00 T500.00 ;Setup Print/Retract/Travel acceleration\n"
    "M205 X8.00 Y8.00 Z0.40 E5.00 ;Setup Jerk\n"
)

USER = {  # the "user" layer: deviations from Cura's own Ender-3 / Standard Quality / Generic PLA
    "machine_width": 220, "machine_depth": 220, "machine_height": 250,
    "machine_gcode_flavor": "RepRap (Marlin/Sprinter)",
    "machine_max_feedrate_x": 500, "machine_max_feedrate_y": 500, "machine_max_feedrate_z": 5, "machine_max_feedrate_e": 25,
    "machine_max_acceleration_x": 500, "machine_max_acceleration_y": 500, "machine_max_acceleration_z": 100,
    "machine_max_acceleration_e": 5000, "machine_acceleration": 500,
    "machine_max_jerk_xy": 8, "machine_max_jerk_z": 0.4, "machine_max_jerk_e": 5,
    "machine_nozzle_size": 0.4, "material_diameter": 1.75,
    "layer_height": 0.2, "layer_height_0": 0.2,
    "wall_line_count": 2,
    "infill_sparse_density": 20, "infill_pattern": "grid",
    "material_print_temperature": 200, "material_print_temperature_layer_0": 200,
    "material_bed_temperature": 60, "material_bed_temperature_layer_0": 60,
    "retraction_enable": True, "retraction_amount": 5, "retraction_speed": 45,
    "support_enable": False,
    "adhesion_type": "skirt", "skirt_line_count": 1,
    "relative_extrusion": False,
    "center_object": True,  # CLI only: centre the model on the bed (X110 Y110) and drop it to z=0
}


def collect(tree, out, only_new=False):
    for key, props in tree.items():
        if not (only_new and key in out):
            out[key] = {p: v for p, v in props.items() if p != "children"}
        if "children" in props:
            collect(props["children"], out, only_new)


def main(res, out_path):
    defs = {}
    collect(json.load(open(f"{res}/definitions/fdmprinter.def.json"))["settings"], defs)
    collect(json.load(open(f"{res}/definitions/fdmextruder.def.json"))["settings"], defs, only_new=True)
    for f in ["definitions/creality_base.def.json", "definitions/creality_ender3.def.json",
              "extruders/creality_base_extruder_0.def.json"]:
        for key, props in json.load(open(f"{res}/{f}")).get("overrides", {}).items():
            defs.setdefault(key, {}).update(props)

    def inst(path):
        cp = configparser.ConfigParser(interpolation=None)
        cp.read(f"{res}/{path}")
        return dict(cp["values"]) if cp.has_section("values") else {}

    quality = inst("quality/creality/base/base_global_standard.inst.cfg")
    quality.update(inst("quality/creality/base/base_0.4_PLA_standard.inst.cfg"))
    variant = inst("variants/creality_base_0.4.inst.cfg")
    ns = {"um": "http://www.ultimaker.com/material"}
    mat_xml = ET.parse(f"{res}/materials/generic_pla.xml.fdm_material").getroot()
    mat_keys = {"print temperature": "default_material_print_temperature",
                "heated bed temperature": "default_material_bed_temperature",
                "standby temperature": "material_standby_temperature",
                "build volume temperature": "build_volume_temperature",
                "adhesion tendency": "material_adhesion_tendency",
                "surface energy": "material_surface_energy"}
    material = {}
    for s in mat_xml.find("um:settings", ns).findall("um:setting", ns):
        if s.get("key") in mat_keys:
            material[mat_keys[s.get("key")]] = s.text.strip()
    # (material_diameter is not taken from the XML: it describes 2.85 mm; Cura derives the 1.75 mm
    # generic_pla_175 container from it and the machine's 1.75 mm, which USER states explicitly.)

    cache = {}

    def convert(key, v):
        t = defs.get(key, {}).get("type", "str")
        if not isinstance(v, str):
            return v
        if t == "float":
            return float(v)
        if t == "int":
            return int(float(v))
        if t == "bool":
            return v.strip() in ("True", "true", "1", "yes", "on")
        if t in ("polygon", "polygons", "[int]"):
            return ast.literal_eval(v)
        return v

    funcs = {
        "math": math,
        "extruderValue": lambda nr, key: resolve(key),
        "extruderValues": lambda key: [resolve(key)],
        "resolveOrValue": lambda key: resolve(key),
        "anyExtruderWithMaterial": lambda key: resolve(key),
        "anyExtruderNrWithOrDefault": lambda key: 0,
        "defaultExtruderPosition": lambda: "0",
    }

    def evaluate(key, expr):
        names = {n.id for n in ast.walk(ast.parse(expr, mode="eval")) if isinstance(n, ast.Name)}
        env = dict(funcs)
        for n in names:
            if n in defs and n not in env:
                env[n] = resolve(n)
        return convert(key, eval(expr, env))

    def resolve(key):
        if key in cache:
            return cache[key]
        if key in USER:
            v = USER[key]
        else:
            for layer in (quality, material, variant):
                if key in layer:
                    raw = layer[key]
                    v = evaluate(key, raw[1:]) if raw.startswith("=") else convert(key, raw)
                    break
            else:
                p = defs[key]
                v = evaluate(key, p["value"]) if isinstance(p.get("value"), str) else \
                    convert(key, p["value"]) if "value" in p else convert(key, p.get("default_value"))
        cache[key] = v
        return v

    def fmt(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return repr(round(v, 9)).removesuffix(".0") if v == v else "nan"
        if isinstance(v, (list, tuple)):
            return json.dumps(v)
        return str(v)

    values = {}
    for key, p in defs.items():
        if p.get("type") == "category":
            continue
        values[key] = resolve(key)
    # the GUI's own start G-code handling: Ender-3 start code (creality_ender3) with creality_base's
    # M201/M203/M204/M205 lines in front, then {setting} tokens expanded.
    values["machine_start_gcode"] = START_GCODE_LIMITS + values["machine_start_gcode"]
    for key in ("machine_start_gcode", "machine_end_gcode"):
        values[key] = re.sub(r"\{(\w+)\}", lambda m: fmt(resolve(m.group(1))) if m.group(1) in defs else m.group(0),
                             values[key])

    doc = {
        "version": 2,
        "name": "Creality Ender-3, Cura 4.13 Standard Quality 0.2 mm, Generic PLA (resolved)",
        "metadata": {"generated_by": "cura_resolve_settings.py (see its docstring)", "user_overrides": USER},
        "settings": {"resolved": {"type": "category",
                                  "children": {k: {"default_value": fmt(values[k])} for k in sorted(values)}}},
    }
    with open(out_path, "w") as f:
        json.dump(doc, f, indent=1, sort_keys=False)
        f.write("\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
