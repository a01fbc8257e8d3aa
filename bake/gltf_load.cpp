/* bake/gltf_load.cpp — the glTF 2.0 adapter: the only file that knows tinygltf.
 *
 * ub_scene_load() reads a .gltf/.glb with tinygltf (Debian's libtinygltf.so holds the
 * implementation, so TINYGLTF_IMPLEMENTATION is NOT defined here), validates everything
 * the rest of ubake will trust (indices, accessor bounds, finite data, tags), flattens the
 * default scene to world space and hands back plain C arrays (include/ubake/scene.h).
 *
 * Internally, errors are thrown as LoadError and caught at the C boundary: no exception
 * ever crosses into C, and every allocation before the final copy is owned by RAII, so a
 * failed load leaks nothing. Warnings are buffered and only logged when the load
 * succeeds, so a failure produces exactly one log line.
 */
#include "ubake/scene.h"
#include "ubake/bakefile.h" /* the record name field tag names must fit */

#include <tiny_gltf.h>
#include <stb_image.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <set>
#include <new>
#include <string>
#include <vector>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace {

const float kDefaultTexelSize = 0.25f;  /* metres per lightmap texel */
const float kDefaultGlgSpacing = 2.0f;  /* metres between GLG probes */
/* A triangle is degenerate when twice its area is below this fraction of its longest
 * edge squared, i.e. its smallest altitude is under 1e-6 of its longest edge. */
const double kDegenerateRel = 1e-6;
/* ...or when that altitude is below what float rounding of its coordinates can produce. */
const double kDegenerateUlps = 8.0;
const double kMaxCoordinate = UB_SCENE_MAX_COORDINATE; /* ubake/scene.h */
/* TEXCOORD_1 may stray this far outside [0,1] (rounding) and is clamped silently. */
const double kUvSlack = 1e-3;
const size_t kMaxWarnings = 20;
/* Images larger than this (pixels) are not decoded; their mean is taken as 1. */
const double kMaxImagePixels = 64.0 * 1024 * 1024;

struct LoadError {
  ub_result code;
  std::string message;
};

std::string vformat(const char *fmt, va_list ap)
{
  char buf[1024];
  vsnprintf(buf, sizeof buf, fmt, ap);
  return buf;
}

/* Makes untrusted text safe for a one-line message: no control characters, bounded. */
std::string clean(const std::string &s, size_t max_len = 96)
{
  std::string out;
  for (unsigned char c : s) {
    if (out.size() >= max_len) {
      out += "...";
      break;
    }
    out += (c < 0x20 || c == 0x7f) ? ' ' : (char)c;
  }
  return out;
}

/* tinygltf's multi-line error text condensed to one line. */
std::string one_line(const std::string &s)
{
  std::string out;
  bool pending_sep = false;
  for (unsigned char c : s) {
    if (c == '\n' || c == '\r') {
      pending_sep = !out.empty();
      continue;
    }
    if (pending_sep) {
      out += "; ";
      pending_sep = false;
    }
    out += (c < 0x20 || c == 0x7f) ? ' ' : (char)c;
  }
  if (out.size() > 400)
    out = out.substr(0, 400) + "...";
  return out;
}

std::string describe(const tinygltf::Value &v)
{
  char buf[64];
  if (v.IsString())
    return "string \"" + clean(v.Get<std::string>(), 48) + "\"";
  if (v.IsNumber()) {
    snprintf(buf, sizeof buf, "number %g", v.GetNumberAsDouble());
    return buf;
  }
  if (v.IsBool())
    return v.Get<bool>() ? "true" : "false";
  if (v.IsArray()) {
    snprintf(buf, sizeof buf, "an array of %zu", v.ArrayLen());
    return buf;
  }
  if (v.IsObject())
    return "an object";
  return "null";
}

bool finite3(const double *v)
{
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

/* 4x4 column-major (glTF order), double precision: node chains compose in double. */
struct Mat4 {
  double m[16];
};

Mat4 mat_identity()
{
  Mat4 r{};
  r.m[0] = r.m[5] = r.m[10] = r.m[15] = 1.0;
  return r;
}

Mat4 mat_mul(const Mat4 &a, const Mat4 &b)
{
  Mat4 r{};
  for (int c = 0; c < 4; c++)
    for (int rr = 0; rr < 4; rr++) {
      double s = 0.0;
      for (int k = 0; k < 4; k++)
        s += a.m[k * 4 + rr] * b.m[c * 4 + k];
      r.m[c * 4 + rr] = s;
    }
  return r;
}

double mat_det3(const Mat4 &a)
{
  const double *m = a.m;
  return m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2]) +
         m[8] * (m[1] * m[6] - m[5] * m[2]);
}

/* Cofactor matrix of the upper 3x3 (row-major out[r][c]) = det × inverse-transpose:
 * maps normals correctly up to scale, even for singular transforms. */
void mat_cofactor3(const Mat4 &a, double out[3][3])
{
  /* element (r,c) of the upper 3x3 */
  auto e = [&](int r, int c) { return a.m[c * 4 + r]; };
  for (int r = 0; r < 3; r++)
    for (int c = 0; c < 3; c++) {
      int r1 = (r + 1) % 3, r2 = (r + 2) % 3, c1 = (c + 1) % 3, c2 = (c + 2) % 3;
      out[r][c] = e(r1, c1) * e(r2, c2) - e(r1, c2) * e(r2, c1);
    }
}

/* Interns names (doors, light sets, objects): index of first appearance. */
struct NameTable {
  std::vector<std::string> names;
  std::map<std::string, int32_t> index;
  int32_t intern(const std::string &s)
  {
    auto it = index.find(s);
    if (it != index.end())
      return it->second;
    int32_t i = (int32_t)names.size();
    names.push_back(s);
    index.emplace(s, i);
    return i;
  }
};

/* Tag state of a node; children inherit their parent's tags unless they set their own. */
struct Tags {
  ub_light_class light_class = UB_LIGHT_STATIC;
  int32_t dls = -1;
  ub_receiver_kind receiver = UB_RECEIVER_LIGHTMAP;
  bool receiver_tagged = false; /* ubake_receiver set on this node or an ancestor */
  int32_t door = -1;
  int32_t door_open = -1;
  int32_t semidynamic = -1;
  float texel_size = 0.0f;
  std::string combine; /* ubake_combine: names of sets/doors combined with this door */
};

struct NodeOut {
  std::string name;
  int32_t gltf_index;
  Tags tags;
  uint32_t first_triangle;
  uint32_t triangle_count;
  bool has_mesh;
  int32_t mesh = -1;   /* glTF mesh index */
  float world[12] = {}; /* world transform, column-major 3×4 */
};

struct MaterialOut {
  float albedo[3];
  float emission[3];
  std::string name;
};

/* Compressed bytes of each image, kept by our image callback; decoded only if a material
 * needs the mean. */
struct ImageCtx {
  tinygltf::Model *model;
};

bool keep_image_bytes(tinygltf::Image *image, const int image_idx, std::string *err,
                      std::string *warn, int req_width, int req_height,
                      const unsigned char *bytes, int size, void *user)
{
  (void)warn;
  (void)req_width;
  (void)req_height;
  const ImageCtx *ctx = static_cast<const ImageCtx *>(user);
  if (image->bufferView >= 0) {
    /* tinygltf hands us &buffer.data[byteOffset] without checking the view fits. */
    const tinygltf::Model &m = *ctx->model;
    bool ok = (size_t)image->bufferView < m.bufferViews.size();
    if (ok) {
      const tinygltf::BufferView &bv = m.bufferViews[(size_t)image->bufferView];
      ok = bv.buffer >= 0 && (size_t)bv.buffer < m.buffers.size() &&
           bv.byteOffset <= m.buffers[(size_t)bv.buffer].data.size() &&
           bv.byteLength <= m.buffers[(size_t)bv.buffer].data.size() - bv.byteOffset;
    }
    if (!ok) {
      if (err)
        *err += "image[" + std::to_string(image_idx) + "] bufferView " +
                std::to_string(image->bufferView) + " is out of range of its buffer\n";
      return false;
    }
  }
  if (bytes && size > 0)
    image->image.assign(bytes, bytes + size);
  image->as_is = true;
  return true;
}

/* Filesystem callbacks for ub_scene_load_memory(): a glTF loaded from memory must be
 * self-contained (data: URIs or the GLB binary chunk); any external URI is refused, so
 * hostile input can never make the loader touch the filesystem. */
bool mem_file_exists(const std::string &, void *) { return false; }
std::string mem_expand_path(const std::string &p, void *) { return p; }
bool mem_read_file(std::vector<unsigned char> *, std::string *err, const std::string &, void *)
{
  if (err)
    *err += "external files cannot be read when loading from memory";
  return false;
}
bool mem_write_file(std::string *err, const std::string &, const std::vector<unsigned char> &,
                    void *)
{
  if (err)
    *err += "writing is not supported";
  return false;
}

/* path opened for reading if it is a regular file, else NULL and *why (cannot open: …;
 * cannot read: Is a directory; not a regular file). Opened without blocking, then checked:
 * a FIFO with no writer would block fopen, /dev/zero be read until 4 GB. */
FILE *open_regular(const std::string &path, std::string *why)
{
  int fd = open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    *why = std::string("cannot open: ") + strerror(errno);
    return nullptr;
  }
  struct stat st;
  if (fstat(fd, &st) != 0) {
    *why = std::string("cannot read: ") + strerror(errno);
    close(fd);
    return nullptr;
  }
  if (!S_ISREG(st.st_mode)) {
    *why = S_ISDIR(st.st_mode) ? std::string("cannot read: ") + strerror(EISDIR)
                               : std::string("not a regular file (a device, pipe or socket)");
    close(fd);
    return nullptr;
  }
  int fl = fcntl(fd, F_GETFL);
  if (fl != -1)
    fcntl(fd, F_SETFL, fl & ~O_NONBLOCK);
  FILE *f = fdopen(fd, "rb");
  if (!f) {
    *why = std::string("cannot open: ") + strerror(errno);
    close(fd);
  }
  return f;
}

/* Filesystem callbacks for a level on disk: tinygltf's own say "File not found" for a
 * buffer or image that is there but cannot be read (permissions); these tell which. */
bool disk_file_exists(const std::string &path, void *)
{
  struct stat st;
  return stat(path.c_str(), &st) == 0;
}
/* The bytes of the regular file at path into *out, stopping past max bytes. 0: read;
 * 1: cannot open it (*why as open_regular says); 2: a read failed (*why: its strerror);
 * 3: larger than max. */
enum { kReadOk = 0, kReadOpen, kReadError, kReadTooLarge };
int read_regular(const std::string &path, size_t max, std::vector<unsigned char> *out,
                 std::string *why)
{
  FILE *f = open_regular(path, why);
  if (!f)
    return kReadOpen;
  out->clear();
  unsigned char chunk[1 << 16];
  size_t n;
  while ((n = fread(chunk, 1, sizeof chunk, f)) > 0) {
    out->insert(out->end(), chunk, chunk + n);
    if (out->size() > max) {
      fclose(f);
      return kReadTooLarge;
    }
  }
  bool bad = ferror(f) != 0;
  int e = errno;
  fclose(f);
  if (bad)
    *why = strerror(e);
  return bad ? kReadError : kReadOk;
}

bool disk_read_file(std::vector<unsigned char> *out, std::string *err, const std::string &path,
                    void *)
{
  std::string why;
  int r = read_regular(path, SIZE_MAX, out, &why);
  if (r != kReadOk && err)
    *err += why;
  return r == kReadOk;
}

class Loader {
public:
  /* data == NULL: read the file at path; else parse data[0..size) and use path as the
   * name in messages only. */
  Loader(const char *path, const ub_log *log, const unsigned char *data = nullptr,
         size_t size = 0)
      : path_(path), log_(log), mem_data_(data), mem_size_(size)
  {
  }

  void load();
  ub_scene *to_c() const; /* NULL on out of memory */
  void flush_warnings() const;

  const std::vector<std::string> &warnings() const { return warnings_; }

private:
  [[noreturn]] void fail(ub_result code, const char *fmt, ...)
#if defined(__GNUC__)
      __attribute__((format(printf, 3, 4)))
#endif
      ;
  void warn(const char *fmt, ...)
#if defined(__GNUC__)
      __attribute__((format(printf, 2, 3)))
#endif
      ;

  void parse_file();
  void parse_bytes(const unsigned char *data, size_t size, const std::string &base_dir,
                   bool self_contained);
  std::string node_label(int idx) const;
  void check_extensions();
  void read_scene_settings(int scene_idx);
  Tags node_tags(int idx, const Tags &parent);
  std::string tag_string(int idx, const std::string &key, const tinygltf::Value &v);
  std::string tag_name(int idx, const std::string &key, const tinygltf::Value &v);
  void check_tag_references();
  float tag_positive(const std::string &where, const std::string &key,
                     const tinygltf::Value &v);
  Mat4 local_matrix(int idx) const;
  void traverse(int scene_idx);
  void add_mesh(int node_idx, const Mat4 &world, NodeOut &out);
  void add_primitive(int node_idx, int mesh_idx, int prim_idx, const Mat4 &world,
                     double det, const double cof[3][3]);
  void add_light(int node_idx, int li, const Mat4 &world, const Tags &tags, int32_t ub_node);
  uint32_t material_index(int m);
  void build_materials();
  void texture_mean(int tex, const std::string &what, float out[3]);
  void read_accessor(int ai, int want_type, const char *semantic, int node_idx,
                     std::vector<float> *out_f, std::vector<uint32_t> *out_u);
  void finish_triangles();

  std::string path_;
  const ub_log *log_;
  const unsigned char *mem_data_; /* non-NULL: load from memory */
  size_t mem_size_;
  tinygltf::Model model_;
  std::vector<std::string> warnings_;
  size_t dropped_warnings_ = 0;

  std::vector<float> pos_, nrm_, uv1_;
  std::vector<uint32_t> idx_, tri_mat_, tri_node_;
  std::vector<uint8_t> flags_;
  std::vector<MaterialOut> mats_;
  int32_t default_material_ = -1;
  std::vector<NodeOut> nodes_;
  std::vector<ub_light> lights_;
  NameTable dls_, doors_, objects_;
  std::vector<int> image_state_;       /* 0 not decoded, 1 ok, -1 failed */
  std::vector<std::array<double, 3>> image_mean_;

  bool has_sky_ = false;
  float sky_[3] = {0, 0, 0};
  float texel_size_ = kDefaultTexelSize;
  float glg_spacing_ = kDefaultGlgSpacing;
  float bmin_[3] = {0, 0, 0}, bmax_[3] = {0, 0, 0};
  uint32_t degenerate_ = 0;
  uint32_t skipped_ = 0;
  uint32_t fixed_normals_ = 0;
  uint32_t dropped_uv1_prims_ = 0;
};

void Loader::fail(ub_result code, const char *fmt, ...)
{
  va_list ap;
  va_start(ap, fmt);
  std::string msg = vformat(fmt, ap);
  va_end(ap);
  throw LoadError{code, clean(path_, 200) + ": " + msg};
}

void Loader::warn(const char *fmt, ...)
{
  if (warnings_.size() >= kMaxWarnings) {
    dropped_warnings_++;
    return;
  }
  va_list ap;
  va_start(ap, fmt);
  std::string msg = vformat(fmt, ap);
  va_end(ap);
  warnings_.push_back(clean(path_, 200) + ": " + msg);
}

void Loader::flush_warnings() const
{
  for (const std::string &w : warnings_)
    ub_log_printf(log_, UB_LOG_WARNING, "%s", w.c_str());
  if (dropped_warnings_)
    ub_log_printf(log_, UB_LOG_WARNING, "%s: %zu more warnings not shown",
                  clean(path_, 200).c_str(), dropped_warnings_);
}

std::string Loader::node_label(int idx) const
{
  const std::string &name = model_.nodes[(size_t)idx].name;
  if (name.empty())
    return "node " + std::to_string(idx);
  return "node " + std::to_string(idx) + " '" + clean(name) + "'";
}

/* Step 1: read the file ourselves (clean I/O errors, .glb detected by its magic), then
 * let tinygltf parse it. */
void Loader::parse_file()
{
  if (mem_data_) {
    if (mem_size_ > 0xFFFFFFF0u)
      fail(UB_ERR_INVALID_DATA, "data is larger than 4 GB");
    parse_bytes(mem_data_, mem_size_, std::string(), true);
    return;
  }
  std::string why;
  std::vector<unsigned char> bytes;
  switch (read_regular(path_, 0xFFFFFFF0u, &bytes, &why)) {
  case kReadOpen:
    fail(UB_ERR_IO, "%s", why.c_str());
  case kReadError:
    fail(UB_ERR_IO, "cannot read: %s", why.c_str());
  case kReadTooLarge:
    fail(UB_ERR_INVALID_DATA, "file is larger than 4 GB");
  }

  std::string base_dir;
  size_t slash = path_.find_last_of('/');
  if (slash != std::string::npos)
    base_dir = path_.substr(0, slash);
  parse_bytes(bytes.data(), bytes.size(), base_dir, false);
}

/* Parses a whole .gltf or .glb (told apart by the GLB magic) with tinygltf. size has been
 * checked to fit an unsigned int. */
void Loader::parse_bytes(const unsigned char *data, size_t size, const std::string &base_dir,
                         bool self_contained)
{
  tinygltf::TinyGLTF gltf;
  ImageCtx ictx{&model_};
  gltf.SetImageLoader(keep_image_bytes, &ictx);
  if (self_contained) {
    tinygltf::FsCallbacks fs = {mem_file_exists, mem_expand_path, mem_read_file,
                                mem_write_file, nullptr};
    gltf.SetFsCallbacks(fs);
  } else {
    tinygltf::FsCallbacks fs = {disk_file_exists, &tinygltf::ExpandFilePath, disk_read_file,
                                &tinygltf::WriteWholeFile, nullptr};
    gltf.SetFsCallbacks(fs);
  }
  std::string err, warn_text;
  bool ok;
  bool is_glb = size >= 4 && memcmp(data, "glTF", 4) == 0;
  /* tinygltf reads a .gltf as JSON text of exactly `size` bytes; an empty buffer still
   * needs a valid pointer. */
  static const unsigned char empty[1] = {0};
  if (size == 0)
    data = empty;
  if (is_glb)
    ok = gltf.LoadBinaryFromMemory(&model_, &err, &warn_text, data, (unsigned int)size,
                                   base_dir);
  else
    ok = gltf.LoadASCIIFromString(&model_, &err, &warn_text,
                                  reinterpret_cast<const char *>(data), (unsigned int)size,
                                  base_dir);
  if (!ok) {
    std::string e = one_line(err.empty() ? "unknown tinygltf error" : err);
    bool io = err.find("File not found") != std::string::npos ||
              err.find("File read error") != std::string::npos;
    fail(io ? UB_ERR_IO : UB_ERR_INVALID_DATA, "%s: %s",
         io ? "cannot read a file it refers to" : is_glb ? "invalid glTF binary" : "invalid glTF",
         e.c_str());
  }
  (void)warn_text; /* image problems are reported by texture_mean(), per material */

  const std::string &ver = model_.asset.version;
  if (ver.size() < 2 || ver[0] != '2' || ver[1] != '.')
    fail(UB_ERR_UNSUPPORTED_VERSION, "asset.version \"%s\" is not glTF 2.x",
         clean(ver, 16).c_str());
}

void Loader::check_extensions()
{
  for (const std::string &e : model_.extensionsRequired) {
    bool supported = e == "KHR_lights_punctual" || e == "KHR_materials_emissive_strength" ||
                     e == "KHR_mesh_quantization" || e == "KHR_texture_transform" ||
                     e.compare(0, 14, "KHR_materials_") == 0;
    if (!supported)
      fail(UB_ERR_INVALID_DATA, "requires extension %s, which ubake does not support",
           clean(e).c_str());
  }
}

/* ---- tags (DESIGN §4) ------------------------------------------------------------- */

std::string Loader::tag_string(int idx, const std::string &key, const tinygltf::Value &v)
{
  if (!v.IsString() || v.Get<std::string>().empty())
    fail(UB_ERR_INVALID_DATA, "%s: %s must be a non-empty string, got %s",
         node_label(idx).c_str(), key.c_str(), describe(v).c_str());
  return v.Get<std::string>();
}

/* tag_string for the name of a set, door or object: the .ubk's records (and the game at run
 * time) name them with at most this many bytes; a longer name would be cut, and two names
 * sharing their first bytes would collide. */
std::string Loader::tag_name(int idx, const std::string &key, const tinygltf::Value &v)
{
  std::string s = tag_string(idx, key, v);
  const size_t max_name = sizeof(ub_bakefile_record::name) - 1;
  if (s.size() > max_name)
    fail(UB_ERR_INVALID_DATA, "%s: %s %s is %zu bytes long; names are at most %zu",
         node_label(idx).c_str(), key.c_str(), describe(v).c_str(), s.size(), max_name);
  return s;
}

float Loader::tag_positive(const std::string &where, const std::string &key,
                           const tinygltf::Value &v)
{
  double d = v.IsNumber() ? v.GetNumberAsDouble() : NAN;
  if (!(std::isfinite(d) && d > 0.0 && d < 1e30))
    fail(UB_ERR_INVALID_DATA, "%s: %s must be a number > 0, got %s", where.c_str(),
         key.c_str(), describe(v).c_str());
  return (float)d;
}

Tags Loader::node_tags(int idx, const Tags &parent)
{
  Tags t = parent;
  const tinygltf::Value &ex = model_.nodes[(size_t)idx].extras;
  if (!ex.IsObject())
    return t;
  for (const std::string &key : ex.Keys()) {
    if (key.compare(0, 6, "ubake_") != 0)
      continue; /* authoring-tool extras: ignored silently */
    const tinygltf::Value &v = ex.Get(key);
    if (key == "ubake_light") {
      std::string s = v.IsString() ? v.Get<std::string>() : std::string();
      if (s == "static")
        t.light_class = UB_LIGHT_STATIC;
      else if (s == "primary")
        t.light_class = UB_LIGHT_PRIMARY;
      else
        fail(UB_ERR_INVALID_DATA, "%s: ubake_light must be \"static\" or \"primary\", got %s",
             node_label(idx).c_str(), describe(v).c_str());
    } else if (key == "ubake_dls") {
      t.dls = dls_.intern(tag_name(idx, key, v));
    } else if (key == "ubake_receiver") {
      std::string s = v.IsString() ? v.Get<std::string>() : std::string();
      t.receiver_tagged = true;
      if (s == "lightmap")
        t.receiver = UB_RECEIVER_LIGHTMAP;
      else if (s == "llg")
        t.receiver = UB_RECEIVER_LLG;
      else if (s == "none")
        t.receiver = UB_RECEIVER_NONE;
      else
        fail(UB_ERR_INVALID_DATA,
             "%s: ubake_receiver must be \"lightmap\", \"llg\" or \"none\", got %s",
             node_label(idx).c_str(), describe(v).c_str());
    } else if (key == "ubake_door") {
      t.door = doors_.intern(tag_name(idx, key, v));
    } else if (key == "ubake_door_open") {
      t.door_open = doors_.intern(tag_name(idx, key, v));
    } else if (key == "ubake_combine") {
      t.combine = tag_string(idx, key, v);
    } else if (key == "ubake_semidynamic") {
      t.semidynamic = objects_.intern(tag_name(idx, key, v));
    } else if (key == "ubake_texel_size") {
      t.texel_size = tag_positive(node_label(idx), key, v);
    } else {
      warn("%s: unknown tag %s ignored", node_label(idx).c_str(), clean(key).c_str());
    }
  }
  return t;
}

/* Scene-level settings: the glTF scene object's extras, else the root extras. */
void Loader::read_scene_settings(int scene_idx)
{
  const tinygltf::Value *sources[2] = {nullptr, &model_.extras};
  std::string labels[2] = {"scene", "root extras"};
  if (scene_idx >= 0) {
    sources[0] = &model_.scenes[(size_t)scene_idx].extras;
    labels[0] = "scene " + std::to_string(scene_idx);
  }
  bool seen_sky = false, seen_texel = false, seen_glg = false;
  for (int s = 0; s < 2; s++) {
    const tinygltf::Value *ex = sources[s];
    if (!ex || !ex->IsObject())
      continue;
    for (const std::string &key : ex->Keys()) {
      if (key.compare(0, 6, "ubake_") != 0)
        continue;
      const tinygltf::Value &v = ex->Get(key);
      if (key == "ubake_sky") {
        bool ok = v.IsArray() && v.ArrayLen() == 3;
        double c[3] = {0, 0, 0};
        for (int i = 0; ok && i < 3; i++) {
          ok = v.Get(i).IsNumber();
          c[i] = ok ? v.Get(i).GetNumberAsDouble() : 0.0;
          ok = ok && std::isfinite(c[i]) && c[i] >= 0.0 && c[i] < 1e30;
        }
        if (!ok)
          fail(UB_ERR_INVALID_DATA,
               "%s: ubake_sky must be [r,g,b] of finite numbers >= 0, got %s",
               labels[s].c_str(), describe(v).c_str());
        if (!seen_sky) {
          has_sky_ = true;
          for (int i = 0; i < 3; i++)
            sky_[i] = (float)c[i];
        }
        seen_sky = true;
      } else if (key == "ubake_texel_size") {
        float x = tag_positive(labels[s], key, v);
        if (!seen_texel)
          texel_size_ = x;
        seen_texel = true;
      } else if (key == "ubake_glg_spacing") {
        float x = tag_positive(labels[s], key, v);
        if (!seen_glg)
          glg_spacing_ = x;
        seen_glg = true;
      } else {
        warn("%s: unknown tag %s ignored", labels[s].c_str(), clean(key).c_str());
      }
    }
  }
}

/* ---- accessors ------------------------------------------------------------------ */

int component_size(int ct)
{
  switch (ct) {
  case TINYGLTF_COMPONENT_TYPE_BYTE:
  case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return 1;
  case TINYGLTF_COMPONENT_TYPE_SHORT:
  case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: return 2;
  case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
  case TINYGLTF_COMPONENT_TYPE_FLOAT: return 4;
  default: return 0; /* INT, DOUBLE and others are not glTF 2.0 accessor types */
  }
}

int type_components(int type)
{
  switch (type) {
  case TINYGLTF_TYPE_SCALAR: return 1;
  case TINYGLTF_TYPE_VEC2: return 2;
  case TINYGLTF_TYPE_VEC3: return 3;
  case TINYGLTF_TYPE_VEC4: return 4;
  default: return 0;
  }
}

double read_component(const unsigned char *p, int ct, bool normalized)
{
  switch (ct) {
  case TINYGLTF_COMPONENT_TYPE_FLOAT: {
    float f;
    memcpy(&f, p, 4);
    return f;
  }
  case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return normalized ? p[0] / 255.0 : p[0];
  case TINYGLTF_COMPONENT_TYPE_BYTE: {
    int8_t v;
    memcpy(&v, p, 1);
    return normalized ? std::max(v / 127.0, -1.0) : v;
  }
  case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
    uint16_t v;
    memcpy(&v, p, 2);
    return normalized ? v / 65535.0 : v;
  }
  case TINYGLTF_COMPONENT_TYPE_SHORT: {
    int16_t v;
    memcpy(&v, p, 2);
    return normalized ? std::max(v / 32767.0, -1.0) : v;
  }
  case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
    uint32_t v;
    memcpy(&v, p, 4);
    return v;
  }
  }
  return 0.0;
}

/* Where `count` elements of `elem` bytes live in a bufferView, bounds-checked.
 * Returns the first element and sets *stride. */
struct ViewCheck {
  const tinygltf::Model &m;
  const unsigned char *locate(int view, size_t offset, size_t count, size_t elem,
                              size_t *stride, std::string *why) const
  {
    if (view < 0 || (size_t)view >= m.bufferViews.size()) {
      *why = "bufferView " + std::to_string(view) + " does not exist";
      return nullptr;
    }
    const tinygltf::BufferView &bv = m.bufferViews[(size_t)view];
    if (bv.buffer < 0 || (size_t)bv.buffer >= m.buffers.size()) {
      *why = "bufferView " + std::to_string(view) + " refers to missing buffer " +
             std::to_string(bv.buffer);
      return nullptr;
    }
    const std::vector<unsigned char> &data = m.buffers[(size_t)bv.buffer].data;
    if (bv.byteOffset > data.size() || bv.byteLength > data.size() - bv.byteOffset) {
      *why = "bufferView " + std::to_string(view) + " (offset " +
             std::to_string(bv.byteOffset) + ", length " + std::to_string(bv.byteLength) +
             ") exceeds its buffer of " + std::to_string(data.size()) + " bytes";
      return nullptr;
    }
    size_t s = bv.byteStride ? bv.byteStride : elem;
    if (s < elem) {
      *why = "bufferView " + std::to_string(view) + " byteStride " + std::to_string(s) +
             " is smaller than an element (" + std::to_string(elem) + " bytes)";
      return nullptr;
    }
    /* offset + s*(count-1) + elem <= byteLength, without overflow (count < 2^32, s <= 252) */
    if (count > 0) {
      unsigned long long need = (unsigned long long)offset +
                                (unsigned long long)s * (unsigned long long)(count - 1) +
                                (unsigned long long)elem;
      if (offset > bv.byteLength || need > (unsigned long long)bv.byteLength) {
        *why = std::to_string(count) + " elements at offset " + std::to_string(offset) +
               " need " + std::to_string(need) + " bytes but bufferView " +
               std::to_string(view) + " has " + std::to_string(bv.byteLength);
        return nullptr;
      }
    }
    *stride = s;
    return data.data() + bv.byteOffset + offset;
  }
};

/* Reads accessor `ai` (of type want_type) as floats or as unsigned integers (indices),
 * applying sparse substitution. Every failure names the node and the accessor. */
void Loader::read_accessor(int ai, int want_type, const char *semantic, int node_idx,
                           std::vector<float> *out_f, std::vector<uint32_t> *out_u)
{
  const char *sem = semantic;
  if (ai < 0 || (size_t)ai >= model_.accessors.size())
    fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d does not exist (%zu accessors)",
         node_label(node_idx).c_str(), sem, ai, model_.accessors.size());
  const tinygltf::Accessor &a = model_.accessors[(size_t)ai];
  int nc = type_components(a.type);
  int cs = component_size(a.componentType);
  if (a.type != want_type || nc == 0)
    fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d has the wrong type (%d components)",
         node_label(node_idx).c_str(), sem, ai, nc);
  if (cs == 0 || (out_u && (a.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT ||
                            a.componentType == TINYGLTF_COMPONENT_TYPE_BYTE ||
                            a.componentType == TINYGLTF_COMPONENT_TYPE_SHORT)))
    fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d has unsupported componentType %d",
         node_label(node_idx).c_str(), sem, ai, a.componentType);
  if (a.count > 0x7FFFFFFFu)
    fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d count %zu is too large",
         node_label(node_idx).c_str(), sem, ai, a.count);

  size_t n = a.count;
  size_t elem = (size_t)nc * (size_t)cs;
  if (out_f)
    out_f->assign(n * (size_t)nc, 0.0f);
  else
    out_u->assign(n, 0u);

  ViewCheck vc{model_};
  std::string why;
  auto put = [&](size_t i, const unsigned char *p) {
    if (out_f) {
      for (int c = 0; c < nc; c++)
        (*out_f)[i * (size_t)nc + (size_t)c] =
            (float)read_component(p + (size_t)c * (size_t)cs, a.componentType, a.normalized);
    } else {
      (*out_u)[i] = (uint32_t)read_component(p, a.componentType, false);
    }
  };

  if (a.bufferView >= 0) {
    size_t stride = 0;
    const unsigned char *base = vc.locate(a.bufferView, a.byteOffset, n, elem, &stride, &why);
    if (!base)
      fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d out of range: %s",
           node_label(node_idx).c_str(), sem, ai, why.c_str());
    for (size_t i = 0; i < n; i++)
      put(i, base + i * stride);
  } else if (!a.sparse.isSparse) {
    /* glTF: an accessor without bufferView and without sparse is all zeros */
  }

  if (a.sparse.isSparse) {
    int sc = a.sparse.count;
    int ict = a.sparse.indices.componentType;
    int ics = (ict == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE || ict == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT ||
               ict == TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)
                  ? component_size(ict)
                  : 0;
    if (sc < 0 || (size_t)sc > n || ics == 0 || a.sparse.indices.byteOffset < 0 ||
        a.sparse.values.byteOffset < 0)
      fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d has an invalid sparse block",
           node_label(node_idx).c_str(), sem, ai);
    size_t istride = 0, vstride = 0;
    const unsigned char *ib =
        vc.locate(a.sparse.indices.bufferView, (size_t)a.sparse.indices.byteOffset,
                  (size_t)sc, (size_t)ics, &istride, &why);
    const unsigned char *vb =
        ib ? vc.locate(a.sparse.values.bufferView, (size_t)a.sparse.values.byteOffset,
                       (size_t)sc, elem, &vstride, &why)
           : nullptr;
    if (!ib || !vb)
      fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d sparse data out of range: %s",
           node_label(node_idx).c_str(), sem, ai, why.c_str());
    /* sparse data is tightly packed */
    for (int k = 0; k < sc; k++) {
      double di = read_component(ib + (size_t)k * (size_t)ics, ict, false);
      if (di >= (double)n)
        fail(UB_ERR_INVALID_DATA, "%s: %s accessor %d sparse index %.0f >= count %zu",
             node_label(node_idx).c_str(), sem, ai, di, n);
      put((size_t)di, vb + (size_t)k * elem);
    }
  }
}

/* ---- nodes ---------------------------------------------------------------------- */

Mat4 Loader::local_matrix(int idx) const
{
  const tinygltf::Node &n = model_.nodes[(size_t)idx];
  Mat4 r = mat_identity();
  auto bad = [&](const char *what) {
    const_cast<Loader *>(this)->fail(UB_ERR_INVALID_DATA, "%s: invalid %s",
                                     node_label(idx).c_str(), what);
  };
  if (!n.matrix.empty()) {
    if (n.matrix.size() != 16)
      bad("matrix (needs 16 numbers)");
    for (int i = 0; i < 16; i++) {
      if (!std::isfinite(n.matrix[(size_t)i]))
        bad("matrix (not finite)");
      r.m[i] = n.matrix[(size_t)i];
    }
    return r;
  }
  double t[3] = {0, 0, 0}, s[3] = {1, 1, 1}, q[4] = {0, 0, 0, 1};
  if (!n.translation.empty()) {
    if (n.translation.size() != 3)
      bad("translation (needs 3 numbers)");
    std::copy(n.translation.begin(), n.translation.end(), t);
  }
  if (!n.scale.empty()) {
    if (n.scale.size() != 3)
      bad("scale (needs 3 numbers)");
    std::copy(n.scale.begin(), n.scale.end(), s);
  }
  if (!n.rotation.empty()) {
    if (n.rotation.size() != 4)
      bad("rotation (needs 4 numbers)");
    std::copy(n.rotation.begin(), n.rotation.end(), q);
  }
  if (!finite3(t) || !finite3(s) || !std::isfinite(q[3]) || !finite3(q))
    bad("translation/rotation/scale (not finite)");
  double ql = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (!(ql > 1e-12))
    bad("rotation (zero quaternion)");
  double x = q[0] / ql, y = q[1] / ql, z = q[2] / ql, w = q[3] / ql;
  double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)},
                    {2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)},
                    {2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)}};
  for (int c = 0; c < 3; c++)
    for (int rr = 0; rr < 3; rr++)
      r.m[c * 4 + rr] = R[rr][c] * s[c];
  r.m[12] = t[0];
  r.m[13] = t[1];
  r.m[14] = t[2];
  return r;
}

void Loader::traverse(int scene_idx)
{
  size_t nn = model_.nodes.size();
  std::vector<int> roots;
  if (scene_idx >= 0) {
    roots = model_.scenes[(size_t)scene_idx].nodes;
  } else {
    /* No scenes: every node that is nobody's child is a root. */
    std::vector<char> is_child(nn, 0);
    for (size_t i = 0; i < nn; i++)
      for (int c : model_.nodes[i].children)
        if (c >= 0 && (size_t)c < nn)
          is_child[(size_t)c] = 1;
    for (size_t i = 0; i < nn; i++)
      if (!is_child[i])
        roots.push_back((int)i);
  }

  struct Item {
    int node;
    Mat4 parent;
    Tags tags;
  };
  std::vector<char> visited(nn, 0);
  std::vector<Item> stack;
  for (size_t r = roots.size(); r-- > 0;) {
    int ri = roots[r];
    if (ri < 0 || (size_t)ri >= nn)
      fail(UB_ERR_INVALID_DATA, "scene %d lists node %d, which does not exist", scene_idx, ri);
    stack.push_back(Item{ri, mat_identity(), Tags()});
  }
  while (!stack.empty()) {
    Item it = stack.back();
    stack.pop_back();
    if (visited[(size_t)it.node])
      fail(UB_ERR_INVALID_DATA, "%s has more than one parent or is its own ancestor",
           node_label(it.node).c_str());
    visited[(size_t)it.node] = 1;
    const tinygltf::Node &n = model_.nodes[(size_t)it.node];
    Mat4 world = mat_mul(it.parent, local_matrix(it.node));
    Tags tags = node_tags(it.node, it.tags);

    int light = -1;
    auto ext = n.extensions.find("KHR_lights_punctual");
    if (ext != n.extensions.end() && ext->second.IsObject() && ext->second.Has("light")) {
      const tinygltf::Value &lv = ext->second.Get("light");
      double d = lv.IsNumber() ? lv.GetNumberAsDouble() : -1.0;
      if (!(d >= 0 && d < 2147483647.0 && d == std::floor(d)))
        fail(UB_ERR_INVALID_DATA, "%s: KHR_lights_punctual.light must be an index, got %s",
             node_label(it.node).c_str(), describe(lv).c_str());
      light = (int)d;
    }
    if (n.mesh >= 0 || light >= 0) {
      NodeOut no;
      no.name = n.name.empty() ? "node " + std::to_string(it.node) : n.name;
      no.gltf_index = it.node;
      no.tags = tags;
      no.first_triangle = (uint32_t)(idx_.size() / 3);
      no.triangle_count = 0;
      no.has_mesh = n.mesh >= 0;
      no.mesh = n.mesh;
      for (int c = 0; c < 4; c++)
        for (int r = 0; r < 3; r++)
          no.world[3 * c + r] = (float)world.m[4 * c + r];
      nodes_.push_back(no);
      int32_t ub_node = (int32_t)nodes_.size() - 1;
      if (n.mesh >= 0)
        add_mesh(it.node, world, nodes_.back());
      if (light >= 0)
        add_light(it.node, light, world, tags, ub_node);
    }
    for (size_t c = n.children.size(); c-- > 0;) {
      int ci = n.children[c];
      if (ci < 0 || (size_t)ci >= nn)
        fail(UB_ERR_INVALID_DATA, "%s: child %d does not exist", node_label(it.node).c_str(),
             ci);
      stack.push_back(Item{ci, world, tags});
    }
  }
}

void Loader::add_light(int node_idx, int li, const Mat4 &world, const Tags &tags,
                       int32_t ub_node)
{
  if (li < 0 || (size_t)li >= model_.lights.size())
    fail(UB_ERR_INVALID_DATA, "%s: light %d does not exist (%zu lights)",
         node_label(node_idx).c_str(), li, model_.lights.size());
  const tinygltf::Light &l = model_.lights[(size_t)li];
  std::string label = node_label(node_idx) + ": light " + std::to_string(li);
  ub_light o;
  memset(&o, 0, sizeof o);
  if (l.type == "point")
    o.type = UB_LIGHT_POINT;
  else if (l.type == "spot")
    o.type = UB_LIGHT_SPOT;
  else if (l.type == "directional")
    o.type = UB_LIGHT_DIRECTIONAL;
  else
    fail(UB_ERR_INVALID_DATA, "%s: unknown type \"%s\"", label.c_str(), clean(l.type).c_str());

  double color[3] = {1, 1, 1};
  if (!l.color.empty()) {
    if (l.color.size() != 3)
      fail(UB_ERR_INVALID_DATA, "%s: color needs 3 numbers", label.c_str());
    std::copy(l.color.begin(), l.color.end(), color);
  }
  if (!finite3(color) || color[0] < 0 || color[1] < 0 || color[2] < 0)
    fail(UB_ERR_INVALID_DATA, "%s: color must be finite and >= 0", label.c_str());
  if (!std::isfinite(l.intensity) || l.intensity < 0)
    fail(UB_ERR_INVALID_DATA, "%s: intensity must be finite and >= 0, got %g", label.c_str(),
         l.intensity);
  if (!std::isfinite(l.range) || l.range < 0)
    fail(UB_ERR_INVALID_DATA, "%s: range must be finite and >= 0, got %g", label.c_str(),
         l.range);
  for (int i = 0; i < 3; i++)
    o.intensity[i] = (float)(color[i] * l.intensity);
  for (int i = 0; i < 3; i++)
    if (!(o.intensity[i] <= UB_SCENE_MAX_INTENSITY))
      fail(UB_ERR_INVALID_DATA, "%s: color x intensity %g is beyond the limit of %g",
           label.c_str(), color[i] * l.intensity, UB_SCENE_MAX_INTENSITY);
  o.range = (float)l.range;
  o.cos_inner = 1.0f;
  o.cos_outer = -1.0f;
  if (o.type == UB_LIGHT_SPOT) {
    double in = l.spot.innerConeAngle, out = l.spot.outerConeAngle;
    if (!std::isfinite(in) || !std::isfinite(out) || in < 0 || out > M_PI / 2 + 1e-9 ||
        in > out || out <= 0)
      fail(UB_ERR_INVALID_DATA,
           "%s: spot cone angles must satisfy 0 <= inner (%g) <= outer (%g) <= pi/2, outer > 0",
           label.c_str(), in, out);
    o.cos_inner = (float)std::cos(in);
    o.cos_outer = (float)std::cos(std::min(out, M_PI / 2));
  }

  for (int i = 0; i < 3; i++)
    o.position[i] = (float)world.m[12 + i];
  double d[3] = {-world.m[8], -world.m[9], -world.m[10]};
  double dl = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  if (!(dl > 1e-30) || !std::isfinite(dl)) {
    if (o.type != UB_LIGHT_POINT)
      fail(UB_ERR_INVALID_DATA, "%s: node transform collapses the light direction",
           label.c_str());
    d[0] = 0;
    d[1] = 0;
    d[2] = -1;
    dl = 1;
  }
  for (int i = 0; i < 3; i++)
    o.direction[i] = (float)(d[i] / dl);
  for (int i = 0; i < 3; i++)
    if (!std::isfinite(o.position[i]) || std::fabs(world.m[12 + i]) > kMaxCoordinate)
      fail(UB_ERR_INVALID_DATA, "%s: position is not finite or beyond %.0f m", label.c_str(),
           kMaxCoordinate);
  o.cls = tags.light_class;
  o.dls = tags.dls;
  o.node = ub_node;
  lights_.push_back(o);
}

/* ---- meshes --------------------------------------------------------------------- */

uint32_t Loader::material_index(int m)
{
  if (m < 0) {
    /* glTF's default material, appended after the file's by build_materials() */
    if (default_material_ < 0)
      default_material_ = (int32_t)model_.materials.size();
    return (uint32_t)default_material_;
  }
  return (uint32_t)m;
}

void Loader::add_mesh(int node_idx, const Mat4 &world, NodeOut &out)
{
  const tinygltf::Node &n = model_.nodes[(size_t)node_idx];
  if ((size_t)n.mesh >= model_.meshes.size())
    fail(UB_ERR_INVALID_DATA, "%s: mesh %d does not exist (%zu meshes)",
         node_label(node_idx).c_str(), n.mesh, model_.meshes.size());
  for (int i = 0; i < 16; i++)
    if (!std::isfinite(world.m[i]))
      fail(UB_ERR_INVALID_DATA, "%s: world transform is not finite",
           node_label(node_idx).c_str());
  double det = mat_det3(world);
  double cof[3][3];
  mat_cofactor3(world, cof);
  const tinygltf::Mesh &mesh = model_.meshes[(size_t)n.mesh];
  for (size_t p = 0; p < mesh.primitives.size(); p++)
    add_primitive(node_idx, n.mesh, (int)p, world, det, cof);
  out.triangle_count = (uint32_t)(idx_.size() / 3) - out.first_triangle;
}

void Loader::add_primitive(int node_idx, int mesh_idx, int prim_idx, const Mat4 &world,
                           double det, const double cof[3][3])
{
  const tinygltf::Primitive &prim =
      model_.meshes[(size_t)mesh_idx].primitives[(size_t)prim_idx];
  std::string where = node_label(node_idx);
  if (prim.mode != -1 && prim.mode != TINYGLTF_MODE_TRIANGLES) {
    warn("%s: mesh %d primitive %d has mode %d (not triangles); skipped", where.c_str(),
         mesh_idx, prim_idx, prim.mode);
    skipped_++;
    return;
  }
  auto attr = [&](const char *name) {
    auto it = prim.attributes.find(name);
    return it == prim.attributes.end() ? -1 : it->second;
  };
  int a_pos = attr("POSITION"), a_nrm = attr("NORMAL"), a_uv1 = attr("TEXCOORD_1");
  if (a_pos < 0) {
    warn("%s: mesh %d primitive %d has no POSITION; skipped", where.c_str(), mesh_idx,
         prim_idx);
    skipped_++;
    return;
  }
  if (prim.material >= 0 && (size_t)prim.material >= model_.materials.size())
    fail(UB_ERR_INVALID_DATA, "%s: mesh %d primitive %d uses material %d, which does not exist",
         where.c_str(), mesh_idx, prim_idx, prim.material);

  std::vector<float> P, N, UV;
  std::vector<uint32_t> I;
  read_accessor(a_pos, TINYGLTF_TYPE_VEC3, "POSITION", node_idx, &P, nullptr);
  size_t nv = P.size() / 3;
  for (size_t i = 0; i < P.size(); i++)
    if (!std::isfinite(P[i]))
      fail(UB_ERR_INVALID_DATA, "%s: POSITION accessor %d vertex %zu is not finite",
           where.c_str(), a_pos, i / 3);
  if (a_nrm >= 0) {
    read_accessor(a_nrm, TINYGLTF_TYPE_VEC3, "NORMAL", node_idx, &N, nullptr);
    if (N.size() != P.size())
      fail(UB_ERR_INVALID_DATA, "%s: NORMAL accessor %d has %zu elements, POSITION has %zu",
           where.c_str(), a_nrm, N.size() / 3, nv);
    for (size_t i = 0; i < N.size(); i++)
      if (!std::isfinite(N[i]))
        fail(UB_ERR_INVALID_DATA, "%s: NORMAL accessor %d vertex %zu is not finite",
             where.c_str(), a_nrm, i / 3);
  }
  bool has_uv1 = false;
  if (a_uv1 >= 0) {
    read_accessor(a_uv1, TINYGLTF_TYPE_VEC2, "TEXCOORD_1", node_idx, &UV, nullptr);
    if (UV.size() / 2 != nv)
      fail(UB_ERR_INVALID_DATA, "%s: TEXCOORD_1 accessor %d has %zu elements, POSITION has %zu",
           where.c_str(), a_uv1, UV.size() / 2, nv);
    has_uv1 = true;
    for (size_t i = 0; i < UV.size(); i++) {
      if (!std::isfinite(UV[i]))
        fail(UB_ERR_INVALID_DATA, "%s: TEXCOORD_1 accessor %d vertex %zu is not finite",
             where.c_str(), a_uv1, i / 2);
      if (UV[i] < -kUvSlack || UV[i] > 1.0 + kUvSlack)
        has_uv1 = false;
      UV[i] = std::min(1.0f, std::max(0.0f, UV[i]));
    }
    if (!has_uv1) {
      warn("%s: mesh %d primitive %d: TEXCOORD_1 (accessor %d) leaves [0,1]; not used as "
           "lightmap UVs",
           where.c_str(), mesh_idx, prim_idx, a_uv1);
      dropped_uv1_prims_++;
    }
  }
  size_t ni;
  if (prim.indices >= 0) {
    read_accessor(prim.indices, TINYGLTF_TYPE_SCALAR, "indices", node_idx, nullptr, &I);
    for (size_t i = 0; i < I.size(); i++)
      if (I[i] >= nv)
        fail(UB_ERR_INVALID_DATA,
             "%s: indices accessor %d element %zu is %u, out of range of %zu vertices",
             where.c_str(), prim.indices, i, I[i], nv);
    ni = I.size();
  } else {
    ni = nv;
  }
  if (ni % 3)
    warn("%s: mesh %d primitive %d: %zu indices is not a multiple of 3; last %zu ignored",
         where.c_str(), mesh_idx, prim_idx, ni, ni % 3);
  size_t nt = ni / 3;
  if (nt == 0)
    return;

  bool flat = N.empty();
  size_t out_v = flat ? nt * 3 : nv;
  if ((unsigned long long)pos_.size() / 3 + out_v > 0xFFFFFFF0ull ||
      (unsigned long long)idx_.size() / 3 + nt > 0xFFFFFFF0ull)
    fail(UB_ERR_INVALID_DATA, "%s: more than 2^32 vertices or triangles", where.c_str());

  /* world-space vertices */
  std::vector<float> WP(nv * 3), WN;
  const double *m = world.m;
  for (size_t v = 0; v < nv; v++) {
    double x = P[v * 3], y = P[v * 3 + 1], z = P[v * 3 + 2];
    for (int r = 0; r < 3; r++) {
      double w = m[r] * x + m[4 + r] * y + m[8 + r] * z + m[12 + r];
      float f = (float)w;
      if (!std::isfinite(f))
        fail(UB_ERR_INVALID_DATA, "%s: POSITION accessor %d vertex %zu is not finite in world "
             "space", where.c_str(), a_pos, v);
      if (std::fabs(w) > kMaxCoordinate)
        fail(UB_ERR_INVALID_DATA, "%s: POSITION accessor %d vertex %zu is %.3g m from the "
             "origin in world space (limit %.0f m)", where.c_str(), a_pos, v, w, kMaxCoordinate);
      WP[v * 3 + (size_t)r] = f;
    }
  }
  double sgn = det < 0 ? -1.0 : 1.0;
  std::vector<char> bad_normal;
  if (!flat) {
    WN.resize(nv * 3);
    bad_normal.assign(nv, 0);
    for (size_t v = 0; v < nv; v++) {
      double x = N[v * 3], y = N[v * 3 + 1], z = N[v * 3 + 2], o[3];
      for (int r = 0; r < 3; r++)
        o[r] = sgn * (cof[r][0] * x + cof[r][1] * y + cof[r][2] * z);
      double l = std::sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
      if (!(l > 1e-30) || !std::isfinite(l)) {
        bad_normal[v] = 1;
        l = 1;
      }
      for (int r = 0; r < 3; r++)
        WN[v * 3 + (size_t)r] = (float)(o[r] / l);
    }
  }

  uint32_t base = (uint32_t)(pos_.size() / 3);
  uint32_t mat = material_index(prim.material);
  uint32_t tnode = (uint32_t)nodes_.size() - 1;
  uint8_t tflags = has_uv1 ? (uint8_t)UB_TRI_HAS_UV1 : (uint8_t)0;
  bool flip = det < 0;
  for (size_t t = 0; t < nt; t++) {
    uint32_t c[3];
    for (int k = 0; k < 3; k++)
      c[k] = I.empty() ? (uint32_t)(t * 3 + (size_t)k) : I[t * 3 + (size_t)k];
    if (flip)
      std::swap(c[1], c[2]);
    if (flat) {
      /* one vertex per corner carrying the triangle's geometric normal */
      const float *a = &WP[c[0] * 3], *b = &WP[c[1] * 3], *d = &WP[c[2] * 3];
      double e1[3], e2[3], g[3];
      for (int r = 0; r < 3; r++) {
        e1[r] = (double)b[r] - a[r];
        e2[r] = (double)d[r] - a[r];
      }
      g[0] = e1[1] * e2[2] - e1[2] * e2[1];
      g[1] = e1[2] * e2[0] - e1[0] * e2[2];
      g[2] = e1[0] * e2[1] - e1[1] * e2[0];
      double l = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
      if (!(l > 0) || !std::isfinite(l)) {
        g[0] = 0;
        g[1] = 1;
        g[2] = 0;
        l = 1;
      }
      for (int k = 0; k < 3; k++) {
        for (int r = 0; r < 3; r++) {
          pos_.push_back(WP[c[k] * 3 + (size_t)r]);
          nrm_.push_back((float)(g[r] / l));
        }
        uv1_.push_back(has_uv1 ? UV[c[k] * 2] : 0.0f);
        uv1_.push_back(has_uv1 ? UV[c[k] * 2 + 1] : 0.0f);
        idx_.push_back(base + (uint32_t)(t * 3 + (size_t)k));
      }
    } else {
      for (int k = 0; k < 3; k++)
        idx_.push_back(base + c[k]);
    }
    tri_mat_.push_back(mat);
    tri_node_.push_back(tnode);
    flags_.push_back(tflags);
  }
  if (!flat) {
    pos_.insert(pos_.end(), WP.begin(), WP.end());
    nrm_.insert(nrm_.end(), WN.begin(), WN.end());
    if (has_uv1)
      uv1_.insert(uv1_.end(), UV.begin(), UV.end());
    else
      uv1_.insert(uv1_.end(), nv * 2, 0.0f);
    /* zero-length (or collapsed) normals: take the geometric normal of a triangle that
     * uses the vertex, else +Y; nothing non-unit leaves the loader */
    size_t first_tri = idx_.size() / 3 - nt;
    for (size_t t = first_tri; t < idx_.size() / 3; t++) {
      const uint32_t *c = &idx_[t * 3];
      bool any = bad_normal[c[0] - base] || bad_normal[c[1] - base] || bad_normal[c[2] - base];
      if (!any)
        continue;
      const float *a = &pos_[c[0] * 3], *b = &pos_[c[1] * 3], *d = &pos_[c[2] * 3];
      double e1[3], e2[3], g[3];
      for (int r = 0; r < 3; r++) {
        e1[r] = (double)b[r] - a[r];
        e2[r] = (double)d[r] - a[r];
      }
      g[0] = e1[1] * e2[2] - e1[2] * e2[1];
      g[1] = e1[2] * e2[0] - e1[0] * e2[2];
      g[2] = e1[0] * e2[1] - e1[1] * e2[0];
      double l = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
      if (!(l > 0) || !std::isfinite(l))
        continue;
      for (int k = 0; k < 3; k++) {
        if (!bad_normal[c[k] - base])
          continue;
        for (int r = 0; r < 3; r++)
          nrm_[c[k] * 3 + (size_t)r] = (float)(g[r] / l);
        bad_normal[c[k] - base] = 0;
        fixed_normals_++;
      }
    }
    for (size_t v = 0; v < nv; v++)
      if (bad_normal[v]) {
        nrm_[(base + v) * 3 + 0] = 0.0f;
        nrm_[(base + v) * 3 + 1] = 1.0f;
        nrm_[(base + v) * 3 + 2] = 0.0f;
        fixed_normals_++;
      }
  }
}

/* Degenerate flags, counts and bounds, all in world space. */
void Loader::finish_triangles()
{
  size_t nt = idx_.size() / 3;
  for (int r = 0; r < 3; r++) {
    bmin_[r] = nt ? FLT_MAX : 0.0f;
    bmax_[r] = nt ? -FLT_MAX : 0.0f;
  }
  for (size_t t = 0; t < nt; t++) {
    const float *v[3];
    for (int k = 0; k < 3; k++)
      v[k] = &pos_[(size_t)idx_[t * 3 + (size_t)k] * 3];
    double e[3][3], lmax2 = 0.0, amax = 0.0;
    for (int k = 0; k < 3; k++) {
      const float *p = v[k], *q = v[(k + 1) % 3];
      double l2 = 0.0;
      for (int r = 0; r < 3; r++) {
        e[k][r] = (double)q[r] - p[r];
        l2 += e[k][r] * e[k][r];
        amax = std::max(amax, (double)std::fabs(p[r]));
      }
      lmax2 = std::max(lmax2, l2);
    }
    double cx = e[0][1] * e[2][2] - e[0][2] * e[2][1];
    double cy = e[0][2] * e[2][0] - e[0][0] * e[2][2];
    double cz = e[0][0] * e[2][1] - e[0][1] * e[2][0];
    double area2 = std::sqrt(cx * cx + cy * cy + cz * cz);
    /* altitude onto the longest edge = area2 / lmax; compare with a fraction of that
     * edge and with the rounding noise of float coordinates of this magnitude */
    double lmax = std::sqrt(lmax2);
    double tol = std::max(kDegenerateRel * lmax, kDegenerateUlps * FLT_EPSILON * amax);
    if (!(lmax > 0.0) || area2 <= tol * lmax) {
      flags_[t] |= UB_TRI_DEGENERATE;
      degenerate_++;
    }
    for (int k = 0; k < 3; k++)
      for (int r = 0; r < 3; r++) {
        bmin_[r] = std::min(bmin_[r], v[k][r]);
        bmax_[r] = std::max(bmax_[r], v[k][r]);
      }
  }
  if (nt == 0)
    fail(UB_ERR_INVALID_DATA, "no geometry: the scene has no triangles (%u non-triangle "
         "primitives skipped)", skipped_);
  if (degenerate_ == nt)
    fail(UB_ERR_INVALID_DATA, "no geometry: all %zu triangles have zero area", nt);
}

/* ---- materials ------------------------------------------------------------------ */

/* Mean of a texture's texels in linear RGB (texels are sRGB-encoded). Missing or
 * undecodable images: warning, mean 1. */
void Loader::texture_mean(int tex, const std::string &what, float out[3])
{
  out[0] = out[1] = out[2] = 1.0f;
  if (tex < 0)
    return;
  if ((size_t)tex >= model_.textures.size())
    fail(UB_ERR_INVALID_DATA, "%s: texture %d does not exist (%zu textures)", what.c_str(), tex,
         model_.textures.size());
  int src = model_.textures[(size_t)tex].source;
  if (src < 0) {
    warn("%s: texture %d has no image ubake can read; its mean is taken as 1", what.c_str(),
         tex);
    return;
  }
  if ((size_t)src >= model_.images.size())
    fail(UB_ERR_INVALID_DATA, "%s: texture %d uses image %d, which does not exist",
         what.c_str(), tex, src);
  if (image_state_.empty()) {
    image_state_.assign(model_.images.size(), 0);
    image_mean_.assign(model_.images.size(), {1.0, 1.0, 1.0});
  }
  tinygltf::Image &img = model_.images[(size_t)src];
  std::string label = "image " + std::to_string(src) +
                      (img.uri.empty() || img.uri.compare(0, 5, "data:") == 0
                           ? std::string()
                           : " '" + clean(img.uri) + "'");
  if (image_state_[(size_t)src] == 0) {
    image_state_[(size_t)src] = -1;
    int w = 0, h = 0, comp = 0;
    const char *problem = nullptr;
    if (img.image.empty() || img.image.size() > 0x7FFFFFFF)
      problem = "could not be loaded";
    else if (!stbi_info_from_memory(img.image.data(), (int)img.image.size(), &w, &h, &comp))
      problem = "could not be decoded";
    else if ((double)w * (double)h > kMaxImagePixels)
      problem = "is too large to average";
    if (!problem) {
      unsigned char *px =
          stbi_load_from_memory(img.image.data(), (int)img.image.size(), &w, &h, &comp, 0);
      if (!px || w < 1 || h < 1 || comp < 1 || comp > 4) {
        problem = "could not be decoded";
      } else {
        double lut[256];
        for (int i = 0; i < 256; i++) {
          double c = i / 255.0;
          lut[i] = c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
        }
        double sum[3] = {0, 0, 0};
        size_t np = (size_t)w * (size_t)h;
        for (size_t p = 0; p < np; p++) {
          const unsigned char *q = px + p * (size_t)comp;
          if (comp < 3) { /* grey (+ alpha) */
            double g = lut[q[0]];
            sum[0] += g;
            sum[1] += g;
            sum[2] += g;
          } else {
            sum[0] += lut[q[0]];
            sum[1] += lut[q[1]];
            sum[2] += lut[q[2]];
          }
        }
        for (int c = 0; c < 3; c++)
          image_mean_[(size_t)src][(size_t)c] = sum[c] / (double)np;
        image_state_[(size_t)src] = 1;
      }
      stbi_image_free(px);
    }
    if (problem)
      warn("%s: %s %s; its mean is taken as 1", what.c_str(), label.c_str(), problem);
    std::vector<unsigned char>().swap(img.image); /* compressed bytes no longer needed */
  }
  for (int c = 0; c < 3; c++)
    out[c] = (float)image_mean_[(size_t)src][(size_t)c];
}

void Loader::build_materials()
{
  for (size_t i = 0; i < model_.materials.size(); i++) {
    const tinygltf::Material &gm = model_.materials[i];
    std::string what = "material " + std::to_string(i) +
                       (gm.name.empty() ? std::string() : " '" + clean(gm.name) + "'");
    MaterialOut mo;
    mo.name = gm.name.empty() ? "material " + std::to_string(i) : gm.name;
    double base[4] = {1, 1, 1, 1};
    const std::vector<double> &bcf = gm.pbrMetallicRoughness.baseColorFactor;
    if (!bcf.empty()) {
      if (bcf.size() != 4)
        fail(UB_ERR_INVALID_DATA, "%s: baseColorFactor needs 4 numbers", what.c_str());
      std::copy(bcf.begin(), bcf.end(), base);
    }
    if (!finite3(base))
      fail(UB_ERR_INVALID_DATA, "%s: baseColorFactor is not finite", what.c_str());
    float tmean[3];
    texture_mean(gm.pbrMetallicRoughness.baseColorTexture.index, what, tmean);
    for (int c = 0; c < 3; c++) {
      double a = base[c] * tmean[c];
      mo.albedo[c] = (float)std::min(0.999, std::max(0.0, a));
    }

    double em[3] = {0, 0, 0};
    if (!gm.emissiveFactor.empty()) {
      if (gm.emissiveFactor.size() != 3)
        fail(UB_ERR_INVALID_DATA, "%s: emissiveFactor needs 3 numbers", what.c_str());
      std::copy(gm.emissiveFactor.begin(), gm.emissiveFactor.end(), em);
    }
    if (!finite3(em) || em[0] < 0 || em[1] < 0 || em[2] < 0)
      fail(UB_ERR_INVALID_DATA, "%s: emissiveFactor must be finite and >= 0", what.c_str());
    double strength = 1.0;
    auto es = gm.extensions.find("KHR_materials_emissive_strength");
    if (es != gm.extensions.end() && es->second.IsObject() &&
        es->second.Has("emissiveStrength")) {
      const tinygltf::Value &v = es->second.Get("emissiveStrength");
      strength = v.IsNumber() ? v.GetNumberAsDouble() : NAN;
      if (!std::isfinite(strength) || strength < 0)
        fail(UB_ERR_INVALID_DATA, "%s: emissiveStrength must be a number >= 0, got %s",
             what.c_str(), describe(v).c_str());
    }
    float emean[3] = {1, 1, 1};
    if (em[0] > 0 || em[1] > 0 || em[2] > 0)
      texture_mean(gm.emissiveTexture.index, what, emean);
    for (int c = 0; c < 3; c++) {
      mo.emission[c] = (float)(em[c] * strength * emean[c]);
      if (!(mo.emission[c] <= UB_SCENE_MAX_INTENSITY))
        fail(UB_ERR_INVALID_DATA, "%s: emission %g (emissiveFactor x emissiveStrength) is "
             "beyond the limit of %g", what.c_str(), em[c] * strength * emean[c],
             UB_SCENE_MAX_INTENSITY);
    }
    mats_.push_back(mo);
  }
  if (default_material_ >= 0) {
    MaterialOut d;
    for (int c = 0; c < 3; c++) {
      d.albedo[c] = 0.999f;
      d.emission[c] = 0.0f;
    }
    d.name = "default"; /* glTF default: baseColorFactor 1 (clamped below 1), no emission */
    mats_.push_back(d);
  }
}

void Loader::load()
{
  parse_file();
  check_extensions();
  int scene = model_.defaultScene;
  if (scene >= 0 && (size_t)scene >= model_.scenes.size())
    fail(UB_ERR_INVALID_DATA, "default scene %d does not exist (%zu scenes)", scene,
         model_.scenes.size());
  if (scene < 0 && !model_.scenes.empty())
    scene = 0;
  read_scene_settings(scene);
  traverse(scene);
  finish_triangles();
  build_materials();
  check_tag_references();
  if (fixed_normals_)
    warn("%u vertex normals were zero or collapsed by their node transform; replaced by "
         "geometric normals", fixed_normals_);
}

/* Tags that name something the level does not have are typos as a rule: each one gets a
 * warning naming the node (the plan lists what it skips, on stdout, among other lines).
 * - ubake_combine on a node that is not (under) a door's closed leaf: ignored;
 * - a ubake_combine name that is neither a dynamic light set nor a door: skipped;
 * - a door with an open leaf (ubake_door_open) but no closed leaf (ubake_door): not baked. */
void Loader::check_tag_references()
{
  /* tags are inherited: a group's typo reaches each of its meshes; warned about once */
  std::set<std::string> said;
  auto warn_once = [&](const std::string &key, const std::string &text) {
    if (said.insert(key).second)
      warn("%s", text.c_str());
  };
  for (const NodeOut &no : nodes_) {
    if (no.tags.combine.empty())
      continue;
    if (no.tags.door < 0) {
      warn_once("off-door " + no.tags.combine,
                "node \"" + clean(no.name, 64) + "\": ubake_combine on a node that is not a "
                "door's closed leaf (ubake_door) is ignored");
      continue;
    }
    const std::string &list = no.tags.combine; /* as the plan reads it */
    size_t pos = 0, at, len;
    while (ub_combine_next(list.c_str(), &pos, &at, &len)) {
      std::string name = list.substr(at, len);
      if (!dls_.index.count(name) && !doors_.index.count(name))
        warn_once("unknown " + name,
                  "node \"" + clean(no.name, 64) + "\": ubake_combine names \"" +
                      clean(name, 64) + "\", which is neither a dynamic light set nor a door: "
                      "skipped");
    }
  }
  std::vector<char> closed(doors_.names.size(), 0), open(doors_.names.size(), 0);
  for (const NodeOut &no : nodes_) {
    if (no.tags.door >= 0 && no.triangle_count)
      closed[(size_t)no.tags.door] = 1;
    if (no.tags.door_open >= 0 && no.triangle_count)
      open[(size_t)no.tags.door_open] = 1;
  }
  for (size_t d = 0; d < doors_.names.size(); d++)
    if (open[d] && !closed[d])
      warn("door \"%s\" has an open leaf (ubake_door_open) but no closed leaf (ubake_door) "
           "with triangles: it is not baked", clean(doors_.names[d], 64).c_str());
}

char *dup_string(const std::string &s)
{
  char *p = (char *)malloc(s.size() + 1);
  if (p)
    memcpy(p, s.c_str(), s.size() + 1);
  return p;
}

template <typename T>
bool dup_array(const std::vector<T> &v, T **out)
{
  *out = nullptr;
  if (v.empty())
    return true;
  *out = (T *)malloc(v.size() * sizeof(T));
  if (!*out)
    return false;
  memcpy(*out, v.data(), v.size() * sizeof(T));
  return true;
}

bool dup_names(const NameTable &t, char ***out, uint32_t *count)
{
  *out = nullptr;
  *count = 0;
  if (t.names.empty())
    return true;
  *out = (char **)calloc(t.names.size(), sizeof(char *));
  if (!*out)
    return false;
  *count = (uint32_t)t.names.size();
  for (size_t i = 0; i < t.names.size(); i++)
    if (!((*out)[i] = dup_string(t.names[i])))
      return false;
  return true;
}

ub_scene *Loader::to_c() const
{
  ub_scene *s = (ub_scene *)calloc(1, sizeof *s);
  if (!s)
    return nullptr;
  bool ok = (s->path = dup_string(path_)) != nullptr;
  s->vertex_count = (uint32_t)(pos_.size() / 3);
  s->triangle_count = (uint32_t)(idx_.size() / 3);
  ok = ok && dup_array(pos_, &s->positions) && dup_array(nrm_, &s->normals) &&
       dup_array(uv1_, &s->uv1) && dup_array(idx_, &s->indices) &&
       dup_array(tri_mat_, &s->tri_material) && dup_array(tri_node_, &s->tri_node) &&
       dup_array(flags_, &s->tri_flags) && dup_array(lights_, &s->lights);
  if (ok)
    s->light_count = (uint32_t)lights_.size();
  if (ok && !mats_.empty()) {
    s->materials = (ub_material *)calloc(mats_.size(), sizeof(ub_material));
    ok = s->materials != nullptr;
    if (ok) {
      s->material_count = (uint32_t)mats_.size();
      for (size_t i = 0; ok && i < mats_.size(); i++) {
        ub_material &m = s->materials[i];
        memcpy(m.albedo, mats_[i].albedo, sizeof m.albedo);
        memcpy(m.emission, mats_[i].emission, sizeof m.emission);
        ok = (m.name = dup_string(mats_[i].name)) != nullptr;
      }
    }
  }
  if (ok && !nodes_.empty()) {
    s->nodes = (ub_node *)calloc(nodes_.size(), sizeof(ub_node));
    ok = s->nodes != nullptr;
    if (ok) {
      s->node_count = (uint32_t)nodes_.size();
      for (size_t i = 0; ok && i < nodes_.size(); i++) {
        const NodeOut &no = nodes_[i];
        ub_node &n = s->nodes[i];
        n.gltf_index = no.gltf_index;
        /* a light-only node carries no triangles and receives nothing */
        n.receiver = no.has_mesh ? no.tags.receiver : UB_RECEIVER_NONE;
        n.receiver_source = no.tags.receiver_tagged ? UB_RECEIVER_TAGGED : UB_RECEIVER_DEFAULT;
        n.mesh = no.has_mesh ? no.mesh : -1;
        memcpy(n.world, no.world, sizeof n.world);
        n.door = no.tags.door;
        n.door_open = no.tags.door_open;
        n.semidynamic = no.tags.semidynamic;
        n.texel_size = no.tags.texel_size;
        if (ok && !no.tags.combine.empty())
          ok = (n.combine = dup_string(no.tags.combine)) != nullptr;
        n.first_triangle = no.first_triangle;
        n.triangle_count = no.triangle_count;
        ok = (n.name = dup_string(no.name)) != nullptr;
      }
    }
  }
  ok = ok && dup_names(dls_, &s->dls_names, &s->dls_count) &&
       dup_names(doors_, &s->door_names, &s->door_count) &&
       dup_names(objects_, &s->object_names, &s->object_count);
  if (!ok) {
    ub_scene_free(s);
    return nullptr;
  }
  s->has_sky = has_sky_;
  memcpy(s->sky, sky_, sizeof s->sky);
  s->texel_size = texel_size_;
  s->glg_spacing = glg_spacing_;
  memcpy(s->bounds_min, bmin_, sizeof s->bounds_min);
  memcpy(s->bounds_max, bmax_, sizeof s->bounds_max);
  s->degenerate_count = degenerate_;
  s->skipped_primitives = skipped_;
  return s;
}

} // namespace

namespace {

/* Runs a Loader and converts the outcome to a result code and one log line. */
ub_result run_loader(Loader &loader, const char *name, const ub_log *log, ub_scene **out_scene)
{
  try {
    loader.load();
    ub_scene *s = loader.to_c();
    if (!s) {
      ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory", name);
      return UB_ERR_OUT_OF_MEMORY;
    }
    loader.flush_warnings();
    ub_log_printf(log, UB_LOG_INFO,
                  "%s: %u triangles (%u degenerate), %u vertices, %u materials, %u nodes, "
                  "%u lights, %u primitives skipped",
                  name, s->triangle_count, s->degenerate_count, s->vertex_count,
                  s->material_count, s->node_count, s->light_count, s->skipped_primitives);
    *out_scene = s;
    return UB_OK;
  } catch (const LoadError &e) {
    ub_log_printf(log, UB_LOG_ERROR, "%s", e.message.c_str());
    return e.code;
  } catch (const std::bad_alloc &) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory", name);
    return UB_ERR_OUT_OF_MEMORY;
  } catch (const std::exception &e) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: invalid glTF: %s", name, one_line(e.what()).c_str());
    return UB_ERR_INVALID_DATA;
  } catch (...) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: invalid glTF (unexpected exception)", name);
    return UB_ERR_INVALID_DATA;
  }
}

} // namespace

extern "C" ub_result ub_scene_load(const char *path, const ub_log *log, ub_scene **out_scene)
{
  if (!path || !out_scene) {
    ub_log_printf(log, UB_LOG_ERROR, "ub_scene_load: %s is NULL", path ? "out_scene" : "path");
    return UB_ERR_INVALID_ARGUMENT;
  }
  try {
    Loader loader(path, log);
    return run_loader(loader, path, log, out_scene);
  } catch (...) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory", path);
    return UB_ERR_OUT_OF_MEMORY;
  }
}

extern "C" ub_result ub_scene_load_memory(const void *data, size_t size, const char *name,
                                          const ub_log *log, ub_scene **out_scene)
{
  if ((!data && size) || !out_scene) {
    ub_log_printf(log, UB_LOG_ERROR, "ub_scene_load_memory: %s is NULL",
                  out_scene ? "data" : "out_scene");
    return UB_ERR_INVALID_ARGUMENT;
  }
  static const unsigned char empty[1] = {0};
  const char *label = name ? name : "(memory)";
  try {
    Loader loader(label, log, data ? static_cast<const unsigned char *>(data) : empty, size);
    return run_loader(loader, label, log, out_scene);
  } catch (...) {
    ub_log_printf(log, UB_LOG_ERROR, "%s: out of memory", label);
    return UB_ERR_OUT_OF_MEMORY;
  }
}
