"""``svbrdf export``: re-target a texture set (native, or another preset's) to an engine's texture-set layout."""

import click

from svbrdf_cli.cli.options import bits_opt, check_format, force_opt, format_opt
from svbrdf_cli.write.presets import PRESETS


@click.command("export")
@click.argument("mapset", type=click.Path(file_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(), help="Folder to write the texture set into (must not exist).")
@click.option("--preset", required=True, type=click.Choice(list(PRESETS)),
              help="Target layout: native maps, glTF 2.0, Unreal (ORM, DirectX normal), Unity HDRP (MaskMap), Blender.")
@bits_opt("PNG bit depth (height maps are always 16-bit).")
@format_opt("File format of linear data maps (normal, roughness, packed masks, height); "
            "exr writes 32-bit float. Base colour stays sRGB PNG.")
@force_opt("an existing output folder (atomically)")
@click.option("--no-ao", is_flag=True, help="Constant ambient occlusion (1) instead of one from the height.")
@click.option("--name", default=None, help="The material's name in Unreal, Unity and Blender file names "
                                           "(default: the set's material: the name or photo it was captured from).")
def export_cmd(mapset, output, preset, bits, fmt, force, no_ao, name):
    """Write a texture set as an engine or DCC texture set, without re-running inference.

    Reads MAPSET (a native set, normal/diffuse/roughness/specular.png, or one
    svbrdf wrote with another preset, through its texture_set.json), converts the
    specular workflow to metallic-roughness where the preset needs it
    (glTF's solveMetallic), flips the normal map's green channel for Unreal,
    integrates a 16-bit height map from the normals, and writes the whole set
    at once: a failure leaves no partial folder behind. texture_set.json in
    the set lists each file's role, colour space and the height map's depth.

    \b
    Examples:
      svbrdf export out/wood -o wood_ue --preset unreal
      svbrdf export out/wood -o wood_gltf --preset gltf --bits 16
      svbrdf export out/wood -o wood_blend --preset blender --format exr --force
    """
    from svbrdf_cli.write.presets import write_preset
    from svbrdf_cli.write.readback import material_name, read_any_set

    check_format(preset, fmt)
    maps = read_any_set(mapset)
    paths = write_preset(preset, output, maps, bits=int(bits), fmt=fmt, force=force, protect=(mapset,),
                         name=name or material_name(mapset), ao=not no_ao)
    h, w = maps["normal"].shape[:2]
    click.echo(f"wrote {output} ({preset}, {len(paths)} files, {w}x{h})", err=True)
