import json, os, sys
def load(tag):
    d = {}
    try:
        for l in open(os.path.join(os.environ.get('RB_ROOT', '/tmp/rb'), f'results_{tag}.jsonl')):
            r = json.loads(l); d[r['case']] = r
    except FileNotFoundError:
        pass
    return d
tags = sys.argv[1:]
rows = [load(t) for t in tags]
cases = ["base","seed2","seed3","el20","el45","v6","v12","r0.8","r1.4","box6","box8","vase","lumpy","half4"]
def cell(r):
    if r is None: return "-"
    if r['exit'] not in (0,):
        return "REFUSED: " + r.get('error','')[-160:].replace('\n',' ').split('error: ')[-1][:110]
    s = f"{r['max_rot_deg']:.2f}° / {r['max_cam_mm']:.1f} mm, {'reliable' if r['reliable'] else 'UNRELIABLE'}"
    if 'mean' in r:
        s += f"; eval mean {r['mean']:.2f} std {r['std']:.2f} p95 {r['p95']:.2f} max {r['max']:.1f}"
    elif 'eval_error' in r:
        s += "; eval: alignment failed"
    s += f"; {r['wall_s']:.0f} s"
    return s
print("| case | " + " | ".join(tags) + " |")
print("|---|" + "---|" * len(tags))
for c in cases:
    print(f"| {c} | " + " | ".join(cell(r.get(c)) for r in rows) + " |")
