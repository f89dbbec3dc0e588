# Copyright 2026 toc_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Collision spheres of the shipped arms (config/spheres/*.yaml) from their URDF collision geometry.

For every link with <collision> elements the surface of its geometry (the STL meshes that
example-robot-data ships, loaded with coal; boxes, cylinders and spheres sampled directly) is
sampled uniformly by area in the link frame.  A sphere budget is spread over the links greedily
(one sphere each, then the next sphere to the link where it shrinks the total sphere volume
most); each link's samples are split into k clusters by k-means (deterministic farthest-point
start) and every cluster gets the smallest enclosing sphere of its points, so every sample and
mesh vertex is covered.  The ignore_pairs are the SRDF's disable_collisions (MoveIt's link
pairs that are adjacent or never collide with the real geometry).

Coverage is then measured on an independent, denser sample: the fraction of collision-surface
points inside the union of a link's spheres, the largest distance of a point outside it, and
the spheres' total volume over the geometry's volume (how loose the cover is).

    PYTHONPATH=. python benchmarks/make_collision_spheres.py           # report only
    PYTHONPATH=. python benchmarks/make_collision_spheres.py --write   # and write the files
"""

import argparse
import os
import xml.etree.ElementTree as ElementTree

import numpy as np

from toc_ros.core.arms import load_arm, load_spheres, self_clearance, sphere_centres
from toc_ros.core.arms.model import example_robot_data_dir

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Sphere budget per arm: the solver evaluates every sphere (and every self-collision pair) at
# every node, so the count stays modest.
BUDGETS = {'panda': 20, 'ur5': 14}
SRDF = {'panda': 'panda_description/srdf/panda.srdf', 'ur5': 'ur_description/srdf/ur5.srdf'}
FIT_SAMPLES = 3000        # surface points per link for the fit
CHECK_SAMPLES = 20000     # independent surface points per link for the coverage figures


def _rpy_matrix(rpy):
    roll, pitch, yaw = rpy
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _triangles_of_mesh(filename, scale):
    import coal
    prefix = 'package://example-robot-data/robots/'
    if not filename.startswith(prefix):
        raise ValueError(f'mesh {filename} is not an example-robot-data mesh')
    mesh = coal.MeshLoader().load(os.path.join(example_robot_data_dir(),
                                               filename[len(prefix):]))
    vertices = np.array(mesh.vertices()) * scale
    faces = np.array([[mesh.tri_indices(i)[j] for j in range(3)]
                      for i in range(mesh.num_tris)])
    return vertices[faces], mesh.computeVolume() * np.prod(scale)


def _triangles_of_box(size):
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * (
        np.asarray(size) / 2)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = []
    for a, b, c, d in quads:
        triangles += [corners[[a, b, c]], corners[[a, c, d]]]
    return np.array(triangles), float(np.prod(size))


def collision_surface(link_element):
    """(triangles (T, 3, 3) in the link frame, volume) of a link's <collision> geometry."""
    triangles, volume = [], 0.0
    for collision in link_element.findall('collision'):
        origin = collision.find('origin')
        xyz = np.fromstring(origin.get('xyz', '0 0 0'), sep=' ') if origin is not None else (
            np.zeros(3))
        rpy = np.fromstring(origin.get('rpy', '0 0 0'), sep=' ') if origin is not None else (
            np.zeros(3))
        geometry = collision.find('geometry')
        mesh, box = geometry.find('mesh'), geometry.find('box')
        if mesh is not None:
            scale = np.fromstring(mesh.get('scale', '1 1 1'), sep=' ')
            tris, vol = _triangles_of_mesh(mesh.get('filename'), scale)
        elif box is not None:
            tris, vol = _triangles_of_box(np.fromstring(box.get('size'), sep=' '))
        else:
            raise ValueError(f'link {link_element.get("name")}: only meshes and boxes are '
                             'handled (the shipped arms have no other collision geometry)')
        triangles.append(tris @ _rpy_matrix(rpy).T + xyz)
        volume += vol
    return np.concatenate(triangles), volume


def sample_surface(triangles, count, rng):
    """Points uniformly distributed by area on the triangles, plus every vertex."""
    edges1, edges2 = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    areas = 0.5 * np.linalg.norm(np.cross(edges1, edges2), axis=1)
    pick = rng.choice(len(triangles), size=count, p=areas / areas.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    points = triangles[pick, 0] + u[:, None] * edges1[pick] + v[:, None] * edges2[pick]
    return np.concatenate([points, triangles.reshape(-1, 3)])


def enclosing_sphere(points, iterations=3000):
    """Approximately smallest sphere holding every point (Badoiu-Clarkson), radius exact."""
    centre = points.mean(axis=0)
    for i in range(iterations):
        far = points[np.argmax(np.sum((points - centre) ** 2, axis=1))]
        centre = centre + (far - centre) / (i + 2)
    return centre, float(np.sqrt(np.max(np.sum((points - centre) ** 2, axis=1))))


def fit_spheres(points, k, iterations=40):
    """Return k spheres covering points: k-means clusters, each with its enclosing sphere."""
    seeds = [int(np.argmin(np.sum((points - points.mean(axis=0)) ** 2, axis=1)))]
    dist = np.sum((points - points[seeds[0]]) ** 2, axis=1)
    for _ in range(1, k):
        seeds.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.sum((points - points[seeds[-1]]) ** 2, axis=1))
    centres = points[seeds].copy()
    for _ in range(iterations):
        label = np.argmin(((points[:, None] - centres[None]) ** 2).sum(axis=2), axis=1)
        centres = np.array([points[label == j].mean(axis=0) if np.any(label == j)
                            else centres[j] for j in range(k)])
    label = np.argmin(((points[:, None] - centres[None]) ** 2).sum(axis=2), axis=1)
    return [enclosing_sphere(points[label == j]) for j in range(k) if np.any(label == j)]


def allocate(link_points, budget):
    """{link: spheres}: one sphere per link, then each extra one where it saves most volume."""
    counts = dict.fromkeys(link_points, 1)
    cache = {}

    def fit(link, k):
        if (link, k) not in cache:
            cache[link, k] = fit_spheres(link_points[link], k)
        return cache[link, k]

    fits = {link: fit(link, 1) for link in link_points}

    def volume(spheres):
        return sum(r ** 3 for _, r in spheres)

    while sum(counts.values()) < budget:
        best = None
        for link in link_points:
            trial = fit(link, counts[link] + 1)
            gain = volume(fits[link]) - volume(trial)
            if best is None or gain > best[0]:
                best = (gain, link, trial)
        _, link, trial = best
        counts[link] += 1
        fits[link] = trial
    return fits


def coverage(points, spheres):
    """(fraction of points inside the union, largest distance of a point outside it)."""
    centres = np.array([c for c, _ in spheres])
    radii = np.array([r for _, r in spheres])
    outside = np.min(np.linalg.norm(points[:, None] - centres[None], axis=2) - radii, axis=1)
    return float(np.mean(outside <= 1e-9)), float(max(outside.max(), 0.0))


def srdf_pairs(name, links):
    """Sorted [a, b] pairs of the SRDF's disable_collisions between the given links."""
    root = ElementTree.parse(os.path.join(example_robot_data_dir(), SRDF[name])).getroot()
    pairs = []
    for element in root.findall('disable_collisions'):
        a, b = element.get('link1'), element.get('link2')
        if a in links and b in links:
            pairs.append(sorted((a, b)))
    return sorted(pairs)


def make(name, budget):
    """Fit the spheres of a named arm; return (YAML text, report lines)."""
    arm = load_arm(name)
    root = ElementTree.fromstring(arm.urdf)
    fit_rng, check_rng = np.random.default_rng(0), np.random.default_rng(1)
    fit_points, check_points, volumes = {}, {}, {}
    for element in root.findall('link'):
        if element.find('collision') is None:
            continue
        triangles, volumes[element.get('name')] = collision_surface(element)
        fit_points[element.get('name')] = sample_surface(triangles, FIT_SAMPLES, fit_rng)
        check_points[element.get('name')] = sample_surface(triangles, CHECK_SAMPLES, check_rng)
    fits = allocate(fit_points, budget)
    pairs = srdf_pairs(name, fits)

    report = [f'{name}: {sum(len(s) for s in fits.values())} spheres on {len(fits)} links']
    worst_out, all_in, all_n = 0.0, 0, 0
    for link, spheres in fits.items():
        frac, out = coverage(check_points[link], spheres)
        loose = sum(4 / 3 * np.pi * r ** 3 for _, r in spheres) / volumes[link]
        report.append(f'  {link:22s} {len(spheres)} spheres, r {min(r for _, r in spheres):.3f}'
                      f'-{max(r for _, r in spheres):.3f} m, surface covered {frac:.4f}, '
                      f'worst outside {1000 * out:.2f} mm, sphere/geometry volume {loose:.1f}')
        worst_out = max(worst_out, out)
        all_in += frac * len(check_points[link])
        all_n += len(check_points[link])
    report.append(f'  all: surface covered {all_in / all_n:.4f}, worst outside '
                  f'{1000 * worst_out:.2f} mm')

    lines = [
        '# Collision spheres of the ' + name + ' (example-robot-data URDF): link_name: '
        '[[x, y, z, r], ...],',
        '# centres in the link frame (m).  Made by benchmarks/make_collision_spheres.py '
        '(k-means on the',
        '# collision meshes, each cluster in its smallest enclosing sphere); measured on '
        f'{CHECK_SAMPLES} surface',
        f'# points per link: {all_in / all_n:.4f} inside the union, worst point '
        f'{1000 * worst_out:.2f} mm outside.',
        '# ignore_pairs: the SRDF disable_collisions (adjacent or never colliding link pairs).',
    ]
    for link, spheres in fits.items():
        rows = ', '.join('[' + ', '.join(f'{x:.4f}' for x in c) + f', {r:.4f}]'
                         for c, r in spheres)
        lines.append(f'{link}: [{rows}]')
    lines.append('ignore_pairs:')
    lines += [f'  - [{a}, {b}]' for a, b in pairs]
    return '\n'.join(lines) + '\n', report


def self_collision_report(name, path):
    """Self-collision pair count and the share of random in-limit states in self-collision."""
    arm = load_arm(name)
    spheres = load_spheres(path, arm)
    rng = np.random.default_rng(2)
    hits = 0
    trials = 2000
    for _ in range(trials):
        q = rng.uniform(arm.lower, arm.upper)
        d = self_clearance(sphere_centres(arm, spheres, q), spheres.radii, spheres.self_pairs)
        hits += bool(len(d) and d.min() < 0)
    return (f'  self-collision: {len(spheres.self_pairs)} sphere pairs; {hits / trials:.3f} of '
            f'{trials} uniform in-limit configurations in self-collision')


def main(argv=None):
    """Report the fit and coverage of the shipped arms' spheres; --write writes them."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--arm', choices=sorted(BUDGETS), action='append')
    parser.add_argument('--budget', type=int, help='spheres per arm (default: BUDGETS)')
    parser.add_argument('--write', action='store_true', help='write config/spheres/<arm>.yaml')
    args = parser.parse_args(argv)
    for name in args.arm or sorted(BUDGETS):
        text, report = make(name, args.budget or BUDGETS[name])
        print('\n'.join(report))
        path = os.path.join(ROOT, 'config', 'spheres', f'{name}.yaml')
        if args.write:
            with open(path, 'w') as stream:
                stream.write(text)
            print(f'  wrote {path}')
            print(self_collision_report(name, path))


if __name__ == '__main__':
    main()
