"""The README's opening picture: the shipped material preview (scenes/material_preview.xml: copper, rough glass,
chromium and a diffuse sphere) rendered as written, with Mitsuba's single-scattering built-ins, beside the same
file with every rough built-in turned into ``msx_posfree`` (model ``heitz``: all scattering orders, unbiased) —
only the BSDF's type changes. Writes docs/images/material_preview.png.

    python3 scripts/readme_picture.py [--spp 256] [--out docs/images/material_preview.png]
"""

import argparse
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
_ROUGH = re.compile(r'<bsdf(\s[^>]*)?\stype="(roughconductor|roughdielectric)"([^>]*)>')


def with_msx(text, model):
    """The scene's text with each rough built-in turned into msx_posfree ``model`` (its parameters kept)."""
    def one(m):
        glass = m.group(2) == "roughdielectric"
        extra = '<string name="model" value="%s"/>' % model + ('<string name="surface" value="dielectric"/>'
                                                                 if glass else "")
        return '<bsdf%s type="msx_posfree"%s>%s' % (m.group(1) or "", m.group(3), extra)
    return _ROUGH.sub(one, text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--model", default="heitz")
    ap.add_argument("--out", default=str(ROOT / "docs" / "images" / "material_preview.png"))
    args = ap.parse_args(argv)
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import mitsuba as mi
    import numpy as np
    from PIL import Image, ImageDraw

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    path = Path(msx.scene_path("material_preview.xml"))
    mi.file_resolver().prepend(str(path.parent))
    text = path.read_text()
    images = []
    for label, source in (("Mitsuba's built-ins (single scattering)", text),
                          ("msx_posfree, model=%s (every order)" % args.model, with_msx(text, args.model))):
        img = np.array(mi.render(mi.load_string(source), spp=args.spp, seed=1))
        print("%s: image mean %.4f" % (label, img.mean()), file=sys.stderr)
        srgb = np.clip(np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(np.maximum(img, 0), 1 / 2.4) - 0.055),
                       0, 1)
        tile = Image.fromarray((srgb * 255 + 0.5).astype(np.uint8))
        ImageDraw.Draw(tile).text((6, 4), label, fill=(255, 255, 255))
        images.append(tile)
    w, h = images[0].size
    out = Image.new("RGB", (2 * w + 4, h), (255, 255, 255))
    out.paste(images[0], (0, 0))
    out.paste(images[1], (w + 4, 0))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out + ".tmp.png"
    out.save(tmp)
    os.replace(tmp, args.out)
    print("wrote %s" % args.out, file=sys.stderr)


if __name__ == "__main__":
    main()
