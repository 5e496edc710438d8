// Self-contained HTML reports (inline SVG plots, tables, preformatted text; no external
// scripts, fonts or style sheets) and the atomic file output every command uses.
//
// Output files are never left half-written: AtomicFile writes to a temporary file next
// to the target ("<name>.tmp-<pid>-<n>") and renames it over the target on Commit();
// when it is destroyed without Commit() (an error unwound the stack) the temporary is
// removed. rename() within one directory is atomic on POSIX file systems, so a reader
// sees either the old file or the complete new one.
//
// HtmlReport and AtomicFile are thread-compatible (one thread at a time per object).
#ifndef OMNICML_REPORT_H_
#define OMNICML_REPORT_H_

#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

namespace omnicml {

// A file written under a temporary name and renamed into place on Commit().
class AtomicFile {
 public:
  // Opens the temporary file (binary mode). Throws omnicml::Error naming the path when
  // it cannot be created (missing directory, no permission).
  explicit AtomicFile(std::filesystem::path target);
  ~AtomicFile();  // removes the temporary unless committed
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  std::ofstream& stream() { return out_; }
  const std::filesystem::path& target() const { return target_; }
  const std::filesystem::path& temp_path() const { return temp_; }

  // Flushes, closes and renames onto the target. Throws omnicml::Error on a write or
  // rename failure (the temporary is then removed). Idempotent.
  void Commit();
  // Closes and removes the temporary without touching the target. Idempotent.
  void Discard();

 private:
  std::filesystem::path target_;
  std::filesystem::path temp_;
  std::ofstream out_;
  bool done_ = false;
};

// Writes `content` to `path` atomically (AtomicFile + Commit). Throws omnicml::Error.
void WriteFileAtomic(const std::filesystem::path& path, std::string_view content);

// Reads a whole text file; throws omnicml::Error naming the path when it cannot be read.
std::string ReadTextFile(const std::filesystem::path& path);

// An HTML page assembled from blocks, rendered by Render() into one string.
class HtmlReport {
 public:
  explicit HtmlReport(std::string title);

  // <h2>/<h3> heading; level is clamped to 1..4.
  void AddHeading(const std::string& text, int level = 2);
  // A paragraph of plain text (escaped).
  void AddParagraph(const std::string& text);
  // A table; every row should have header.size() cells (shorter rows are padded).
  void AddTable(const std::vector<std::string>& header,
                const std::vector<std::vector<std::string>>& rows);
  // A key/value list rendered as a two-column table.
  void AddKeyValues(const std::vector<std::pair<std::string, std::string>>& items);
  // Preformatted text (escaped), e.g. a configuration or a text table.
  void AddPreformatted(const std::string& text);
  // An <svg> element inserted verbatim (from SvgPlot::Render or the map drawer).
  void AddSvg(const std::string& svg);
  // Raw, trusted HTML inserted verbatim.
  void AddRawHtml(const std::string& html);

  std::string Render() const;

 private:
  std::string title_;
  std::vector<std::string> blocks_;
};

}  // namespace omnicml

#endif  // OMNICML_REPORT_H_
