"""Closed triangle surfaces written as files, for the meshing tests: icospheres in millimetres,
optionally with triangles left out (a segmentation's hole)."""
import numpy as np
import trimesh

__all__ = ['R_MM', 'ball_volume', 'sphere_file']

#: the radius of the test organ [mm]
R_MM = 20.0


def sphere_file(path, radius_mm, centre=(0.0, 0.0, 0.0), drop=(), subdivisions=4):
    """An icosphere of ``radius_mm`` at ``centre`` written to ``path`` (any trimesh format),
    without the triangles ``drop``; returns the path."""
    ball = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_mm)
    faces = np.delete(np.asarray(ball.faces), list(drop), axis=0)
    trimesh.Trimesh(np.asarray(ball.vertices) + centre, faces, process=False).export(path)
    return path


def ball_volume(radius_mm):
    """4/3 pi r^3 [m^3] of a ball of radius ``radius_mm``."""
    return 4.0 / 3.0 * np.pi * (radius_mm * 1e-3) ** 3
