"""Opens a QGIS project headless and prints one line per layer, tab-separated:
name, valid (1/0), renderer type, xmin, ymin, xmax, ymax, source, and the renderer QGIS gives
the source when it is added on its own (from the .qml style beside it).
With a second argument, renders the visible layers at the project's extent to that PNG.
Used by tests/integration/run_all.rs (python3-qgis, Debian)."""
import os
import sys

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from qgis.core import (  # noqa: E402
    QgsApplication,
    QgsMapRendererParallelJob,
    QgsMapSettings,
    QgsProject,
    QgsRasterLayer,
)
from qgis.PyQt.QtCore import QSize  # noqa: E402
from qgis.PyQt.QtGui import QColor  # noqa: E402

app = QgsApplication([], False)
app.initQgis()
project = QgsProject.instance()
if not project.read(sys.argv[1]):
    print("cannot read project: " + project.error(), file=sys.stderr)
    sys.exit(2)
root = project.layerTreeRoot()
for node in root.findLayers():
    layer = node.layer()
    if layer is None:
        print("\t".join([node.name(), "0", "none", "0", "0", "0", "0", "", "none"]))
        continue
    e = layer.extent()
    renderer = layer.renderer().type() if layer.renderer() else "none"
    alone = QgsRasterLayer(layer.source(), "alone")
    sidecar = alone.renderer().type() if alone.isValid() and alone.renderer() else "none"
    del alone
    print("\t".join([
        layer.name(), "1" if layer.isValid() else "0", renderer,
        repr(e.xMinimum()), repr(e.yMinimum()), repr(e.xMaximum()), repr(e.yMaximum()),
        layer.source(), sidecar,
    ]))
if len(sys.argv) > 2:
    settings = QgsMapSettings()
    settings.setLayers([n.layer() for n in root.findLayers() if n.isVisible() and n.layer()])
    settings.setBackgroundColor(QColor(255, 255, 255))
    settings.setOutputSize(QSize(1000, 800))
    settings.setExtent(project.viewSettings().defaultViewExtent()
                       if not project.viewSettings().defaultViewExtent().isEmpty()
                       else root.findLayers()[0].layer().extent())
    job = QgsMapRendererParallelJob(settings)
    job.start()
    job.waitForFinished()
    job.renderedImage().save(sys.argv[2], "png")
project.clear()
app.exitQgis()
