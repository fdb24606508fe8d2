"""Exports of a fitted material: gonio JSON, Mitsuba 3 (stock and plugin), glTF, MERL and a README."""
