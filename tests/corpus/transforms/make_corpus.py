"""The malformed dataset corpus (see README.md): one valid Blender-layout dataset and one
folder per way of breaking it."""
import json, os, struct, zlib, shutil
# Regenerates this folder: python3 tests/corpus/transforms/make_corpus.py (deterministic).
root = os.path.dirname(os.path.abspath(__file__))
for d in os.listdir(root):
    if os.path.isdir(os.path.join(root, d)):
        shutil.rmtree(os.path.join(root, d))

def png(w, h, rgba=(200, 80, 40, 255)):
    raw = b''.join(b'\x00' + bytes(rgba) * w for _ in range(h))
    def chunk(t, d):
        return struct.pack('>I', len(d)) + t + d + struct.pack('>I', zlib.crc32(t + d) & 0xffffffff)
    return b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, 6, 0, 0, 0)) + chunk(b'IDAT', zlib.compress(raw, 9)) + chunk(b'IEND', b'')

ANGLE = 0.6911112070083618
P0 = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
P1 = [[0, 0, 1, 4], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]]

def base():
    return {"camera_angle_x": ANGLE, "frames": [
        {"file_path": "./train/r_0", "transform_matrix": P0},
        {"file_path": "./train/r_1", "transform_matrix": P1}]}

def case(name, train=None, text=None, images=((16, 16), (16, 16)), extra=None):
    d = os.path.join(root, name)
    os.makedirs(os.path.join(d, 'train'))
    for k, size in enumerate(images):
        if size is not None:
            with open(os.path.join(d, 'train', f'r_{k}.png'), 'wb') as f:
                f.write(png(*size))
    if text is None:
        text = json.dumps(train if train is not None else base(), indent=1)
    with open(os.path.join(d, 'transforms_train.json'), 'w') as f:
        f.write(text + '\n')
    for rel, content in (extra or {}).items():
        p = os.path.join(d, rel)
        os.makedirs(os.path.dirname(p), exist_ok=True)
        with open(p, 'wb') as f:
            f.write(content)

case('valid_blender')
case('invalid_json', text=json.dumps(base(), indent=1)[:120])
t = base(); del t['camera_angle_x']; case('missing_camera_angle_x', t)
t = base(); del t['frames'][1]['transform_matrix']; case('missing_transform_matrix', t)
t = base(); del t['frames'][0]['file_path']; case('missing_file_path', t)
t = base(); t['frames'] = []; case('empty_frames', t)
t = base(); t['frames'][1]['transform_matrix'] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4]]; case('pose_3_rows', t)
t = base(); t['frames'][1]['transform_matrix'] = [[0, 0, 1, 4], [0, 0, 1, 0], [-1, 0, 0, 0], [0, 0, 0, 1]]; case('singular_pose', t)
t = base(); t['frames'][1]['transform_matrix'] = [[0, 0, 2, 4], [0, 2, 0, 0], [-2, 0, 0, 0], [0, 0, 0, 1]]; case('scaled_pose', t)
t = base(); t['frames'][0]['transform_matrix'] = [[1, 0, 0, float('nan')], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]; case('nan_pose', t)  # Python writes NaN
t = base(); case('overflowing_pose', text=json.dumps(t, indent=1).replace('4\n', '1e999\n', 1))
t = base(); t['frames'][1]['file_path'] = './train/r_7'; case('missing_image', t)
case('undecodable_image', extra={'train/r_1.png': png(16, 16)[:40]}, images=((16, 16), None))
case('mixed_image_sizes', images=((16, 16), (24, 16)))
t = base(); t.update(w=32, h=32); case('w_h_disagree_with_image', t)
t = base(); t.update(w=16, h=16, fl_x=12.0, fl_y=12.0, cx=8.0, cy=8.0); case('fl_x_disagrees_with_camera_angle_x', t)
t = base(); t['camera_angle_x'] = 0.0; case('zero_camera_angle_x', t)
t = base(); t.update(w=16, h=16, fl_x=-22.3, fl_y=22.3, cx=8.0, cy=8.0); t['camera_angle_x'] = ANGLE; case('negative_focal_length', t)
t = base(); t['frames'][0]['gt_file_path'] = './train/r_0_gt.exr'; case('missing_ground_truth_file', t)
val = {"camera_angle_x": ANGLE, "frames": {"file_path": "./train/r_0", "transform_matrix": P0}}
case('val_frames_not_a_list', extra={'transforms_val.json': (json.dumps(val, indent=1) + '\n').encode()})
d = os.path.join(root, 'no_train_split'); os.makedirs(os.path.join(d, 'test'))
with open(os.path.join(d, 'test', 'r_0.png'), 'wb') as f: f.write(png(16, 16))
with open(os.path.join(d, 'transforms_test.json'), 'w') as f:
    f.write(json.dumps({"camera_angle_x": ANGLE, "frames": [{"file_path": "./test/r_0", "transform_matrix": P0}]}, indent=1) + '\n')
