#!/usr/bin/env python3
"""The paper's loss x weighting study, from Python.

Solves one view graph with every robust loss (squared, Huber, Soft L1, L0.5,
Cauchy, Geman-McClure, Tukey, MAGSAC++) and every edge weighting (none, inlier
count, trace, Frobenius norm, full covariance), scores each solution against
the ground truth, and prints one table per metric (median error in degrees
and AUC at the chosen threshold), rows the losses and columns the weightings,
as in Table 2 of Zhang, Larsson and Barath (CVPR 2023).

    # a graph written by `rotavg images --graph-out` and its ground truth
    python3 loss_weighting_study.py --graph graph.txt --gt castle-P19 --self-calibration floor
    # any graph file rotavg reads, with the paper's covariance scaling
    python3 loss_weighting_study.py --graph EGs.txt --gt gt.csv --normalization paper
    # no files: a synthetic graph with anisotropic covariances and outliers
    python3 loss_weighting_study.py --synthetic 200

Run it after sourcing the workspace (source devel/setup.bash), so that
`import rotation_averaging` finds the package.
"""
import argparse
import sys
import time

import numpy as np

import rotation_averaging as ra


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--graph", help="view-graph file (1DSfM, g2o, TORO, iRotAvg, rotavg)")
    source.add_argument("--synthetic", type=int, metavar="VIEWS", help="a synthetic graph of this many views")
    parser.add_argument("--gt", help="ground truth for --graph (Strecha folder, COLMAP images.txt, CSV, graph)")
    parser.add_argument("--normalization", default="std", choices=["std", "paper"],
                        help="covariance units for covariance weighting (default: std)")
    parser.add_argument("--self-calibration", default="loss_scale", choices=["loss_scale", "floor"],
                        help="optimistic covariances: widen the loss (default) or add a covariance floor "
                             "(what `rotavg images` does)")
    parser.add_argument("--auc", type=float, default=5.0, help="AUC threshold in degrees (default 5)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the synthetic graph")
    parser.add_argument("--markdown", help="also write the tables to this file")
    args = parser.parse_args(argv)

    if args.graph:
        if not args.gt:
            parser.error("--graph needs --gt")
        graph = ra.read_graph(args.graph)
        truth = ra.read_ground_truth(args.gt)
        title = args.graph
    else:
        graph, truth, is_outlier = ra.synthetic_graph(num_views=args.synthetic, mean_degree=8, noise_deg=2.0,
                                                      noise_spread=5.0, anisotropic=True, outlier_ratio=0.2,
                                                      seed=args.seed)
        title = (f"synthetic graph: {graph.num_views} views, {graph.num_edges} edges, "
                 f"{int(is_outlier.sum())} outliers, anisotropic covariances")
    for warning in graph.warnings[:5]:
        print("warning:", warning, file=sys.stderr)

    losses = ra.loss_names()
    weightings = ra.weighting_names()
    median = np.full((len(losses), len(weightings)), np.nan)
    auc = np.full_like(median, np.nan)
    start = time.perf_counter()
    for a, loss in enumerate(losses):
        for b, weighting in enumerate(weightings):
            solution = ra.solve(graph, loss=loss, weighting=weighting, covariance_normalization=args.normalization,
                                self_calibration=args.self_calibration)
            scores = ra.evaluate(solution.named(), truth, auc_thresholds_deg=[args.auc])
            median[a, b] = scores["median_error_deg"]
            auc[a, b] = 100.0 * scores["auc"][args.auc]
    elapsed = time.perf_counter() - start

    lines = [f"# Loss x weighting: {title}", ""]
    for name, table, fmt, best in (("median error (deg)", median, "{:.3f}", np.nanmin),
                                   (f"AUC@{args.auc:g} (%)", auc, "{:.1f}", np.nanmax)):
        lines += [f"## {name}", "", "| loss | " + " | ".join(weightings) + " |",
                  "|---|" + "---:|" * len(weightings)]
        top = best(table)
        for a, loss in enumerate(losses):
            cells = [("**" + fmt.format(v) + "**") if v == top else fmt.format(v) for v in table[a]]
            lines.append(f"| {loss} | " + " | ".join(cells) + " |")
        lines.append("")
    lines.append(f"{len(losses) * len(weightings)} solves in {elapsed:.2f} s; best value of each table in bold.")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        with open(args.markdown, "w") as f:
            f.write(text + "\n")
    # The study's claim, checked where the covariances are known to be right:
    # on a synthetic graph MAGSAC with covariance weighting is (near) the best.
    if args.synthetic:
        m = median[losses.index("magsac"), weightings.index("covariance")]
        if m > 1.5 * np.nanmin(median):
            print(f"MAGSAC + covariance ({m:.3f} deg) is not among the best here", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
