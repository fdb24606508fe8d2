"""Hypothesis strategies for every model over its whole documented parameter domain."""

import numpy as np
from hypothesis import strategies as st

import model as m

unit = st.floats(0.0, 1.0)
rgb = st.tuples(unit, unit, unit)
channel = unit | rgb
alpha = st.floats(1e-6, 2.0)
exponent = st.floats(0.0, 1e4)


@st.composite
def split_albedo(draw):
    """rho_d, rho_s with rho_d + rho_s <= 1."""
    total = draw(unit)
    share = draw(unit)
    return total * share, total * (1 - share)


@st.composite
def phong(draw):
    d, s = draw(split_albedo())
    return m.Phong(d, s, draw(exponent))


@st.composite
def blinn_phong(draw):
    d, s = draw(split_albedo())
    return m.BlinnPhong(d, s, draw(exponent))


@st.composite
def cook_torrance(draw):
    fres = draw(st.sampled_from(["conductor", "dielectric", "schlick"]))
    dist = draw(st.sampled_from(["ggx", "beckmann", "blinn_phong"]))
    eta = draw(st.floats(0.01, 10.0) | st.tuples(*[st.floats(0.01, 10.0)] * 3))
    return m.CookTorrance(
        alpha=draw(st.floats(1e-6, 1.0) if dist == "blinn_phong" else alpha),
        distribution=dist,
        masking=draw(st.sampled_from(["smith", "smith_correlated", "smith_schlick", "v_groove", "none"])),
        fresnel=fres,
        eta=eta,
        k=draw(st.floats(0.0, 1000.0)),
        f0=draw(channel),
        rho_d=draw(channel) if draw(st.booleans()) else 0.0,
        form=draw(st.sampled_from(["walter", "cook_torrance_1982"])),
    )


@st.composite
def ward(draw):
    d, s = draw(split_albedo())
    return m.Ward(d, s, draw(st.floats(1e-4, 2.0)), draw(st.floats(1e-4, 2.0)),
                  draw(st.sampled_from(["ward", "duer", "balanced"])))


@st.composite
def ashikhmin_shirley(draw):
    return m.AshikhminShirley(draw(channel), draw(channel), draw(exponent), draw(exponent))


@st.composite
def lafortune(draw):
    n = draw(exponent)
    c = st.floats(-2, 2).filter(lambda v: abs(v) <= 1 or n * np.log10(abs(v)) <= 30)
    lobe = m.LafortuneLobe(draw(c), draw(c), draw(c), n)
    return m.Lafortune(draw(channel), (lobe,))


models = st.one_of(
    st.builds(m.Lambert, channel),
    phong(),
    blinn_phong(),
    cook_torrance(),
    ward(),
    ashikhmin_shirley(),
    st.builds(m.OrenNayar, channel, st.floats(0.0, np.pi / 2)),
    lafortune(),
    st.builds(m.KajiyaKay, channel, st.floats(0, 10), exponent, st.floats(-np.pi, np.pi)),
    st.builds(m.MetalnessMix, channel, st.floats(1e-3, 1.0), unit),
    st.builds(m.MetalRoughness, channel, unit, st.floats(1e-3, 1.0)),
)

# Cosines from exactly 0 through 1e-12 to 1, as the project's extremes require.
cosine = st.sampled_from([0.0, 5e-324, 1e-300, 1e-30, 1e-12, 1e-7, 1e-3, 1.0]) | st.floats(0.0, 1.0)


@st.composite
def direction(draw):
    c = draw(cosine)
    phi = draw(st.floats(-np.pi, np.pi))
    s = np.sqrt(max(0.0, 1 - c * c))
    return np.array([s * np.cos(phi), s * np.sin(phi), c])


@st.composite
def pair(draw):
    """A direction pair, sometimes equal, mirrored, or nearly opposite in azimuth."""
    wi = draw(direction())
    kind = draw(st.sampled_from(["free", "equal", "mirror", "opposite"]))
    if kind == "equal":
        return wi, wi.copy()
    if kind == "mirror":
        return wi, np.array([-wi[0], -wi[1], wi[2]])
    if kind == "opposite":
        c = draw(cosine)
        s = np.sqrt(max(0.0, 1 - c * c)) / max(np.hypot(wi[0], wi[1]), 1e-300)
        wo = np.array([-wi[0] * s, -wi[1] * s, c])
        return wi, wo if np.hypot(wi[0], wi[1]) > 0 else np.array([1.0, 0.0, 0.0])
    return wi, draw(direction())
